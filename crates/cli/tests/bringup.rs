//! `ecsync bringup` end to end: the JSON it prints against the segment's ground truth, its pcap
//! against Wireshark's EtherCAT dissector, its errors against bad input.

use std::path::PathBuf;
use std::process::Command;

fn ecsync() -> Command {
    Command::new(env!("CARGO_BIN_EXE_ecsync"))
}

/// Runs `ecsync bringup` with `args`; it must succeed (its error printed if not).
fn bringup_ok(args: &[&str]) -> std::process::Output {
    let out = ecsync().arg("bringup").args(args).output().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

fn tmp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("ecsync-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

#[test]
fn paper_2024_bringup_json_meets_the_acceptance() {
    let out = bringup_ok(&["--preset", "paper-2024", "--json"]);
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let slaves = v["slaves"].as_array().unwrap();
    assert_eq!(slaves.len(), 6);
    for s in slaves {
        let d = s["delay_ns"].as_f64().unwrap();
        let t = s["true_delay_ns"].as_f64().unwrap();
        assert!(
            (d - t).abs() <= 20.0,
            "position {}: {d} vs {t}",
            s["position"]
        );
        assert!(s["position"].is_u64());
    }
    let lock = &v["lock"];
    assert_eq!(lock["converged"], true);
    assert!(lock["time_to_lock_ms"].as_f64().unwrap() > 0.0);
    let max = lock["max_abs_diff_ns"].as_f64().unwrap();
    assert!(max < 100.0, "max |slave - reference| after lock: {max} ns");
}

/// A capture that cannot be created is refused before the bring-up, in the OS's words (it said
/// "pcap capture: Error reading bytes", pcap-file's text for any I/O error).
#[test]
fn a_capture_that_cannot_be_created_is_refused_in_the_os_s_words() {
    let path = tmp("no-such-folder").join("x.pcap");
    let out = ecsync()
        .args(["bringup", "--preset", "paper-2024", "--pcap"])
        .arg(&path)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        err.contains(&format!("cannot create {}", path.display()))
            && err.contains("No such file or directory")
            && !err.contains("Error reading bytes"),
        "{err}"
    );
    assert!(out.stdout.is_empty(), "nothing brought up first");
}

/// With no monitoring nothing reads 0x092C in OP: the output says so rather than a 0 ns that
/// reads as a measurement; with monitoring, the figure is there.
#[test]
fn no_monitoring_prints_no_0x092c_figure() {
    let run = |cycles: &str| {
        let out = bringup_ok(&["--preset", "paper-2024", "--monitor-cycles", cycles]);
        let json = bringup_ok(&[
            "--preset",
            "paper-2024",
            "--json",
            "--monitor-cycles",
            cycles,
        ]);
        let v: serde_json::Value = serde_json::from_slice(&json.stdout).unwrap();
        (
            String::from_utf8_lossy(&out.stdout).into_owned(),
            v["lock"]["max_abs_092c_ns"].clone(),
        )
    };
    let (text, value) = run("0");
    assert!(text.contains("0x092C not read in OP"), "{text}");
    assert!(!text.contains("largest |0x092C| read"), "{text}");
    assert!(value.is_null(), "{value}");
    let (text, value) = run("10");
    assert!(text.contains("largest |0x092C| read"), "{text}");
    assert!(value.as_u64().is_some_and(|v| v < 100), "{value}");
}

/// tshark from Debian's packages (.ci/run installs it), or a panic saying so: the test that
/// calls it is `#[ignore = "needs tshark"]` and runs only when asked for, where a missing
/// tshark is a failure, not a pass.
fn tshark() -> Command {
    let ok = Command::new("tshark")
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success());
    assert!(ok, "this test needs tshark: apt-get install tshark");
    Command::new("tshark")
}

/// `ecsync bringup --pcap` into `name`: the capture and the frame count the JSON reports.
fn bringup_pcap(name: &str) -> (PathBuf, u64) {
    let pcap = tmp(name);
    let out = bringup_ok(&[
        "--json",
        "--static-drift",
        "2000",
        "--monitor-cycles",
        "50",
        "--pcap",
        pcap.to_str().unwrap(),
    ]);
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let frames = v["pcap_frames"].as_u64().unwrap();
    assert!(frames > 1000);
    (pcap, frames)
}

/// The capture holds as many Ethernet frames as the JSON says, each EtherCAT (EtherType
/// 0x88A4), read back with pcap-file (without Wireshark: the dissector's test is below).
#[test]
fn pcap_holds_every_frame_the_bringup_reports() {
    let (pcap, frames) = bringup_pcap("bringup-count.pcap");
    let file = std::fs::File::open(&pcap).unwrap();
    let mut r = pcap_file::pcap::PcapReader::new(file).expect("a pcap header");
    assert_eq!(r.header().datalink, pcap_file::DataLink::ETHERNET);
    let mut n = 0u64;
    while let Some(p) = r.next_packet() {
        let p = p.expect("a whole packet");
        assert_eq!(p.data[12..14], [0x88, 0xa4], "frame {n} is EtherCAT");
        n += 1;
    }
    assert_eq!(n, frames);
}

#[test]
#[ignore = "needs tshark"]
fn pcap_is_read_by_tsharks_ethercat_dissector_without_malformed_frames() {
    let (pcap, frames) = bringup_pcap("bringup.pcap");
    let mut t = tshark();
    // Every frame decodes as EtherCAT; none is malformed or carries an error-level expert item.
    let protos = t
        .arg("-r")
        .arg(&pcap)
        .args(["-T", "fields", "-e", "frame.protocols"])
        .output()
        .unwrap();
    assert!(protos.status.success());
    let protos = String::from_utf8(protos.stdout).unwrap();
    assert_eq!(protos.lines().count() as u64, frames);
    // (A frame with mailbox messages decodes as ecat_mailbox inside, once per message: the
    // drives' mailboxes are served side by side, several in one frame.)
    let ecat = |l: &str| {
        l.strip_prefix("eth:ethertype:ecatf:ecat")
            .is_some_and(|rest| {
                rest.is_empty()
                    || rest
                        .strip_prefix(':')
                        .is_some_and(|r| r.split(':').all(|p| p == "ecat_mailbox"))
            })
    };
    assert!(
        protos.lines().all(ecat),
        "every frame is EtherCAT: {}",
        protos.lines().find(|l| !ecat(l)).unwrap_or("")
    );
    // The drives' sync mode set over CoE: the dissector reads the SDO downloads of 0x1C32:01
    // and 0x1C33:01 (expedited, 2 bytes) and their responses, six drives each.
    let sdo = tshark()
        .arg("-r")
        .arg(&pcap)
        .args([
            "-Y",
            "ecat_mailbox.coe.sdoidx == 0x1c32 && ecat_mailbox.coe.sdosub == 1",
            "-T",
            "fields",
            "-e",
            "ecat_mailbox.coe.sdoreq",
            "-e",
            "ecat_mailbox.coe.sdodata",
        ])
        .output()
        .unwrap();
    let sdo = String::from_utf8_lossy(&sdo.stdout).to_string();
    // One line per frame, the frame's messages comma-separated (several drives' in a frame):
    // six writes of the value 2, each seen going out and coming back (the capture holds
    // both).
    let writes_of_2 = sdo
        .lines()
        .filter_map(|l| l.split('\t').nth(1))
        .flat_map(|d| d.split(','))
        .filter(|v| *v == "0x0002")
        .count();
    assert_eq!(writes_of_2, 12, "SDO writes of 0x1C32:01: {sdo}");
    let bad = tshark()
        .arg("-r")
        .arg(&pcap)
        .args(["-Y", "_ws.malformed || _ws.expert.severity >= error"])
        .output()
        .unwrap();
    assert!(bad.status.success());
    assert_eq!(String::from_utf8_lossy(&bad.stdout), "", "malformed frames");
    // The dissector reads the fields we sent: the first reply is the BRD that counted the six
    // slaves (working counter 6, ADP incremented to 6).
    let first = tshark()
        .arg("-r")
        .arg(&pcap)
        .args([
            "-c", "2", "-T", "fields", "-e", "ecat.cmd", "-e", "ecat.adp", "-e", "ecat.cnt",
        ])
        .output()
        .unwrap();
    let lines: Vec<String> = String::from_utf8(first.stdout)
        .unwrap()
        .lines()
        .map(str::to_string)
        .collect();
    assert_eq!(
        lines,
        ["0x07\t0x0000\t0", "0x07\t0x0006\t6"],
        "BRD request and reply"
    );
}

#[test]
fn bad_config_names_file_line_field_and_fix() {
    let path = tmp("bad.toml");
    let text = ecsync_sim::preset::PAPER_2024_TOML.replace("ppm = -31.7", "ppmm = -31.7");
    std::fs::write(&path, text).unwrap();
    let out = ecsync()
        .arg("bringup")
        .arg("--config")
        .arg(&path)
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("bad.toml:"), "{err}");
    assert!(err.contains("ppmm"), "{err}");
    assert!(err.contains("fix:"), "{err}");
    assert!(!err.contains("panicked"), "{err}");
    let out = ecsync()
        .args(["bringup", "--preset", "nope"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("paper-2024"));
}

/// Every network in `presets/` is usable by name: `--preset twelve-drives` brings up its
/// twelve drives (the file's own count), and an unknown name lists the ones there are.
#[test]
fn every_preset_network_is_usable_by_name() {
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../presets/twelve-drives.toml"
    ))
    .unwrap();
    let declared = text.matches("[[segment.slave]]").count();
    let o = bringup_ok(&["--preset", "twelve-drives", "--json"]);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["slaves"].as_array().unwrap().len(), declared);
    let o = ecsync()
        .args(["bringup", "--preset", "no-such-net"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(err.contains("paper-2024, twelve-drives"), "{err}");
}

/// A drive's crystal past what its time control loop follows of the reference's (763 ppm at
/// Speed Counter Start 0x1000, from the datasheet's formula for 0x0932) never locked: the
/// bring-up ran its 30 s and said only "DC did not lock". Refused now with the slave, its line
/// and the range; just inside the range the simulated bring-up locks.
#[test]
fn a_crystal_the_loop_cannot_follow_is_refused_and_one_just_inside_locks() {
    let dir = tmp("crystal");
    std::fs::create_dir_all(&dir).unwrap();
    let write = |name: &str, ppm: &str| {
        let f = dir.join(name);
        let text = include_str!("../../../presets/paper-2024.toml").replacen(
            "ppm = 44.1",
            &format!("ppm = {ppm}"),
            1,
        );
        std::fs::write(&f, text).unwrap();
        f
    };
    let far = write("far.toml", "800");
    let o = ecsync()
        .args(["bringup", "--config"])
        .arg(&far)
        .output()
        .unwrap();
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        e.contains("far.toml:") && e.contains("segment.slave[2].ppm") && e.contains("763 ppm"),
        "{e}"
    );
    // 774 - 12.4 = 761.6 ppm from the reference: inside the range, and it locks.
    let near = write("near.toml", "774");
    let o = bringup_ok(&["--config", near.to_str().unwrap(), "--json"]);
    let j: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(j["lock"]["converged"], true, "{j}");
}

/// The file's `[run]` holds for the bring-up as for compare: `static_drift_frames` (the option
/// overrides it), and the cycle and SYNC0
/// shift (SYNC0 starts on the file's grid at its shift).
#[test]
fn the_files_run_table_sets_the_bringup() {
    let preset = std::fs::read_to_string(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../presets/paper-2024.toml"),
    )
    .unwrap();
    let text = preset
        .replace("static_drift_frames = 15000", "static_drift_frames = 100")
        .replace("sync0_shift_pct = 30", "sync0_shift_pct = 40")
        .replace("cycle_us = 1000", "cycle_us = 500");
    assert_ne!(text, preset);
    let f = tmp("run-table.toml");
    std::fs::write(&f, text).unwrap();
    let json = |extra: &[&str]| -> serde_json::Value {
        let mut args = vec!["--config", f.to_str().unwrap(), "--json"];
        args.extend_from_slice(extra);
        serde_json::from_slice(&bringup_ok(&args).stdout).unwrap()
    };
    let frmw = |v: &serde_json::Value| v["lock"]["frmw_frames"].as_u64().unwrap();
    let from_file = json(&[]);
    let from_option = json(&["--static-drift", "350"]);
    assert!(frmw(&from_file) < 15_000, "{}", frmw(&from_file));
    // The file's 100 is the option's 100 (the same run, frame for frame); 350 sends more.
    assert_eq!(frmw(&json(&["--static-drift", "100"])), frmw(&from_file));
    assert!(frmw(&from_option) > frmw(&from_file) + 200);
    let start = from_file["sync0_start_ns"].as_u64().unwrap();
    assert_eq!(
        start % 500_000,
        200_000,
        "SYNC0 at 40 % of a 500 us cycle: {start}"
    );
    // The preset itself: 30 % of 1 ms.
    let v: serde_json::Value =
        serde_json::from_slice(&bringup_ok(&["--preset", "paper-2024", "--json"]).stdout).unwrap();
    assert_eq!(v["sync0_start_ns"].as_u64().unwrap() % 1_000_000, 300_000);
}

/// The table names each slave as the scenario does (drives of one device told apart), with the
/// device's own name beside it; `--json` gives both (`config_name`, `name`).
#[test]
fn slaves_are_named_as_the_scenario_names_them() {
    let preset = std::fs::read_to_string(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../presets/paper-2024.toml"),
    )
    .unwrap();
    // A line: network position k is the file's k-th slave.
    let axes = ["axis-x", "axis-y", "axis-z", "axis-u", "axis-v", "axis-w"];
    let mut text = preset.clone();
    for (k, a) in axes.iter().enumerate() {
        text = text.replace(&format!("\"drive-{}\"", k + 1), &format!("\"{a}\""));
    }
    let f = tmp("axes.toml");
    std::fs::write(&f, &text).unwrap();
    let v: serde_json::Value =
        serde_json::from_slice(&bringup_ok(&["--config", f.to_str().unwrap(), "--json"]).stdout)
            .unwrap();
    let slaves = v["slaves"].as_array().unwrap();
    let names: Vec<&str> = slaves
        .iter()
        .map(|s| s["config_name"].as_str().unwrap())
        .collect();
    assert_eq!(names, axes);
    assert!(
        slaves
            .iter()
            .all(|s| s["name"] == "ecsync virtual servo drive")
    );
    let out = bringup_ok(&["--config", f.to_str().unwrap()]);
    let table = String::from_utf8_lossy(&out.stdout);
    for (k, a) in axes.iter().enumerate() {
        let row = table
            .lines()
            .find(|l| l.trim_start().starts_with(&format!("{k}  0x")))
            .unwrap_or_else(|| panic!("no row {k}: {table}"));
        assert!(
            row.contains(&format!(" {a} ")) && row.contains("ecsync virtual servo drive"),
            "{row}"
        );
    }
}

/// An oversampling terminal is brought up on SYNC1 as `compare` brings it up: SYNC1 once a
/// cycle, SYNC0 `oversampling` times a cycle (the preset's figures, the datasheet's rule of
/// 0x09A4), the drive beside it on SYNC0 once a cycle. It was set up as a plain SYNC0 slave.
#[test]
fn an_oversampling_terminal_is_brought_up_on_sync1() {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../presets/oversampling.toml"
    );
    let preset: toml::Value = toml::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    let cycle_ns = preset["run"]["cycle_us"].as_integer().unwrap() as u64 * 1000;
    let out = bringup_ok(&["--preset", "oversampling", "--json"]);
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let slaves = v["slaves"].as_array().unwrap();
    let mut terminals = 0;
    for spec in preset["segment"]["slave"].as_array().unwrap() {
        let name = spec["name"].as_str().unwrap();
        let s = slaves.iter().find(|s| s["config_name"] == name).unwrap();
        let sync = &s["sync"];
        match spec.get("oversampling").and_then(|n| n.as_integer()) {
            Some(n) => {
                terminals += 1;
                assert_eq!(sync["outputs_on"], "sync1", "{name}: {sync}");
                assert_eq!(sync["sync1_period_ns"].as_u64(), Some(cycle_ns), "{name}");
                assert_eq!(
                    sync["sync0_cycle_ns"].as_u64(),
                    Some(cycle_ns / n as u64),
                    "{name}"
                );
            }
            None if spec.get("device").and_then(|d| d.as_str()) == Some("servo-drive") => {
                assert_eq!(sync["outputs_on"], "sync0", "{name}: {sync}");
                assert_eq!(sync["sync0_cycle_ns"].as_u64(), Some(cycle_ns), "{name}");
            }
            None => {}
        }
    }
    assert_eq!(terminals, 1);
    let text = bringup_ok(&["--preset", "oversampling"]);
    let text = String::from_utf8_lossy(&text.stdout);
    assert!(
        text.contains("(analog-out) takes its outputs at SYNC1 every 1000.0 us, with SYNC0 every 250.0 us (4 per SYNC1)"),
        "{text}"
    );
}
