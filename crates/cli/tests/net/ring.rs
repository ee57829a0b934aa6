//! Issue 34, acceptance 2, on a real network: a ring of twelve drives served on two veth pairs
//! (`serve --ring-iface`: the last drive's port 1 cabled back to the master's second port)
//! and ecsync's `run --ring-iface` in redundancy mode (every frame on both ports, the copies
//! made one). The cable between drives 5 and 6 is pulled for 2 s by serve's fault schedule.
//!
//! The truth is the segment's, read by serve's judge: every drive stays in OP with no AL
//! error, and no drive's clock is ever more than 100 ns from the reference's (ground truth,
//! through the break and after it). The run's own figures: the ring found broken once and
//! whole once, some 2 000 frames made of both sides' copies, every LRW with the whole
//! ring's working counter but where one copy came back late (this shared host's stalls,
//! which lose a frame whole elsewhere, as in every other test here).

use super::checked_run::csv_column;
use super::soem::python;
use super::{NetPair, ONE_AT_A_TIME, Served, tmp};
use ecsync_sim::preset;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// The twelve-drives preset with its last drive's port 1 cabled back to the master's second
/// port.
fn ring_toml() -> String {
    let t = preset::TWELVE_DRIVES_TOML;
    let last = "name = \"drive-12\"\n";
    assert!(t.contains(last), "the preset's last drive is drive-12");
    t.replace(last, &format!("{last}ring_port = 1\nring_cable_m = 2.0\n"))
}

/// The cable at port 1 of drive 5 (to drive 6) pulled from 3 s to 5 s after the first frame
/// with process data.
const FAULTS: &str = "[[fault]]\nat_s = 3\nfor_s = 2\nkind = \"link_down\"\nslave = 5\nport = 1\n";

/// Stops serve as Ctrl-C does (its judge writes its files then) and waits for it.
fn stop(served: &mut Served) {
    let pid = served.child.id().to_string();
    let _ = Command::new("kill")
        .args(["-INT", &pid])
        .stderr(Stdio::null())
        .status();
    let t0 = Instant::now();
    while served.child.try_wait().unwrap().is_none() {
        assert!(t0.elapsed() < Duration::from_secs(10), "serve did not stop");
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// The judge's summary.json in `dir`.
fn judge_of(dir: &std::path::Path) -> serde_json::Value {
    serde_json::from_str(
        &std::fs::read_to_string(dir.join("summary.json")).expect("the judge's summary"),
    )
    .unwrap()
}

#[test]
#[ignore = "needs network namespaces (root)"]
fn a_ring_served_on_two_veth_pairs_keeps_every_drive_through_a_pulled_cable() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let pair = NetPair::new("r");
    let (ring_a, ring_b) = pair.second_pair();
    let dir = tmp("ring");
    let (config, faults) = (dir.join("ring.toml"), dir.join("faults.toml"));
    std::fs::write(&config, ring_toml()).unwrap();
    std::fs::write(&faults, FAULTS).unwrap();
    let judge_dir = dir.join("judge");
    let mut served = pair.serve(&[
        "--ring-iface",
        &ring_a,
        "--config",
        config.to_str().unwrap(),
        "--faults",
        faults.to_str().unwrap(),
        "--out",
        judge_dir.to_str().unwrap(),
    ]);
    let csv = dir.join("cycles.csv");
    let o = pair
        .run(&[
            "--ring-iface",
            &ring_b,
            "--duration",
            "9",
            // A reply held up by a stall of this shared host is late, not lost.
            "--timeout-us",
            "100000",
            "--csv",
            csv.to_str().unwrap(),
            "--json",
        ])
        .output()
        .expect("run ecsync run");
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "ecsync run --ring-iface: {stderr}");
    stop(&mut served);
    let j: serde_json::Value = serde_json::from_slice(&o.stdout).expect("JSON summary");
    let judge = judge_of(&judge_dir);
    println!(
        "run: redundancy {}, lost {}, bad wkc {}; judge: faults {}",
        j["redundancy"], j["lost_frames"], j["bad_wkc"], judge["faults"]
    );

    // The ring, as the master's frames showed it.
    let r = &j["redundancy"];
    assert_eq!(r["breaks"], 1, "{r}");
    assert_eq!(r["restores"], 1, "{r}");
    assert_eq!(r["broken_at_end"], false, "{r}");
    let merged = r["merged"].as_u64().unwrap();
    // A frame a cycle for 2 s, and the drives' counters read over CoE once a second.
    assert!((1_500..=2_600).contains(&merged), "{r}");
    // A frame of which one copy came back by its deadline (the other late: this shared host)
    // has one side's working counter: those alone, and none on most runs.
    let partial = r["partial"].as_u64().unwrap();
    assert!(partial <= 20, "{r}");
    // (And the frame after it may go without the far side's copy too, before the late copy
    // comes and says the far side answers.)
    assert!(
        j["bad_wkc"].as_u64().unwrap() <= 2 * partial,
        "{}",
        j["bad_wkc"]
    );
    assert!(j["left_op"].is_null(), "a drive left OP: {}", j["left_op"]);
    for rec in j["recoveries"].as_array().unwrap() {
        assert!(rec["slaves"].as_array().unwrap().is_empty(), "{rec}");
    }
    // Every frame that came back came back whole but the partial ones (a lost frame's row has
    // no lrw_wkc), the ~2 000 of the break merged from both sides' copies.
    let wkc = csv_column(&csv, "lrw_wkc");
    let not_whole = wkc.iter().filter(|&&w| w != 36.0).count() as u64;
    assert!(not_whole <= 2 * partial, "{not_whole} LRWs not whole");
    let start = &judge["faults"][0];
    let (pull_s, plug_s) = (
        start["start_s"].as_f64().unwrap(),
        start["end_s"].as_f64().unwrap(),
    );
    assert!((plug_s - pull_s - 2.0).abs() < 0.01, "{start}");
    // Drives in OP through it (ground truth), none of them with an AL error.
    let in_op = start["drives_in_op"].as_array().unwrap().len();
    assert_eq!(in_op, 12, "{start}");
    for d in judge["drives"].as_array().unwrap() {
        assert_eq!(d["al_state"], "Op", "{d}");
        assert_eq!(d["al_errors"], 0, "{d}");
        // Every drive's clock within 100 ns of the reference's all along (every 8th frame).
        let dev = d["deviation_max_ns"].as_f64().unwrap();
        assert!(
            dev < 100.0,
            "drive {}: {dev} ns from the reference",
            d["name"]
        );
    }
    // Frames lost: this shared host's stalls only (a reply past its cycle's deadline: a
    // handful in 9 000 cycles, with or without a ring); a break sends each side's copy back
    // by its own port and loses none.
    let lost = j["lost_frames"].as_u64().unwrap();
    assert!(lost <= 20, "{lost} frames lost");
    served.kill();
}

/// SOEM's redundancy (pysoem's `open(ifname, ifname_red)`) on the same ring, whole: it
/// measures the propagation delays with the ring closed, where its BWR of 0x0900 leaves by the
/// second port and never comes back through any slave's port 1, so the port 1 receive times
/// it reads were never latched (0 on this segment since power-up; whatever an earlier latch
/// left on silicon). The delays it writes to 0x0928 are tens of milliseconds a hop,
/// and the drives' clocks end up tens to hundreds of microseconds apart while SOEM sees every
/// working counter right: the judge's ground truth says what SOEM cannot. (ecsync's bring-up
/// closes the last slave's port 1 while it measures: the test above, every drive within
/// 100 ns.)
#[test]
#[ignore = "needs network namespaces (root), pysoem"]
fn soem_redundancy_measures_the_delays_on_the_closed_ring_and_its_clocks_drift_apart() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let py = python();
    let pair = NetPair::new("q");
    let (ring_a, ring_b) = pair.second_pair();
    let dir = tmp("soem-ring");
    let config = dir.join("ring.toml");
    std::fs::write(&config, ring_toml()).unwrap();
    let judge_dir = dir.join("judge");
    let mut served = pair.serve(&[
        "--ring-iface",
        &ring_a,
        "--config",
        config.to_str().unwrap(),
        "--out",
        judge_dir.to_str().unwrap(),
    ]);
    let script =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/pysoem/soem_cycle.py");
    let o = Command::new("ip")
        .args(["netns", "exec", &pair.ns_b, &py])
        .arg(&script)
        .arg(&pair.if_b)
        .args([
            "--ring-iface",
            &ring_b,
            "--slaves",
            "12",
            "--cycle-us",
            "1000",
        ])
        .args(["--cycles", "2000", "--max-wkc-errors", "100000"])
        .output()
        .expect("run pysoem");
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "pysoem: {out} {}",
        String::from_utf8_lossy(&o.stderr)
    );
    stop(&mut served);
    let judge = judge_of(&judge_dir);
    println!("SOEM: {out}");
    // SOEM's own check: every working counter right.
    assert!(out.contains(" 0 working counter errors"), "{out}");
    let drives = judge["drives"].as_array().unwrap();
    let dev: Vec<f64> = drives
        .iter()
        .map(|d| d["deviation_max_ns"].as_f64().unwrap())
        .collect();
    let td: Vec<f64> = drives
        .iter()
        .map(|d| d["time_diff_mean_ns"].as_f64().unwrap_or(0.0))
        .collect();
    println!("deviation from the reference, ns: {dev:?}\n|0x092C| mean, ns: {td:?}");
    // The reference itself aside, every drive's clock more than 10 us from the reference's
    // at some point, and its 0x092C (the delay error it is steered by) beyond a millisecond.
    for p in 1..drives.len() {
        assert!(dev[p] > 10_000.0, "drive {}: {} ns", p + 1, dev[p]);
        assert!(td[p] > 1e6, "drive {}: |0x092C| {} ns", p + 1, td[p]);
    }
    served.kill();
}
