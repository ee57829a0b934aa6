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
use super::ring_common::{PULL_5_6, check_ring_through_the_pull, ring_toml};
use super::soem::python;
use super::{NetPair, ONE_AT_A_TIME, Served, tmp};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

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
fn judge_of(dir: &Path) -> serde_json::Value {
    serde_json::from_str(
        &std::fs::read_to_string(dir.join("summary.json")).expect("the judge's summary"),
    )
    .unwrap()
}

/// The ring served in A on the pair's end and `ring_a`, its judge's files into `dir`/judge,
/// with the fault schedule `faults` if given; the judge's folder.
fn serve_ring(pair: &NetPair, ring_a: &str, dir: &Path, faults: Option<&str>) -> (Served, PathBuf) {
    let config = dir.join("ring.toml");
    std::fs::write(&config, ring_toml()).unwrap();
    let judge_dir = dir.join("judge");
    let mut args = vec![
        "--ring-iface".to_string(),
        ring_a.to_string(),
        "--config".into(),
        config.display().to_string(),
        "--out".into(),
        judge_dir.display().to_string(),
    ];
    if let Some(f) = faults {
        let path = dir.join("faults.toml");
        std::fs::write(&path, f).unwrap();
        args.extend(["--faults".to_string(), path.display().to_string()]);
    }
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    (pair.serve(&args), judge_dir)
}

#[test]
#[ignore = "needs network namespaces (root)"]
fn a_ring_served_on_two_veth_pairs_keeps_every_drive_through_a_pulled_cable() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let pair = NetPair::new("r");
    let (ring_a, ring_b) = pair.second_pair();
    let dir = tmp("ring");
    let (mut served, judge_dir) = serve_ring(&pair, &ring_a, &dir, Some(PULL_5_6));
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
    let partial = check_ring_through_the_pull(&j, &judge_of(&judge_dir));
    // Every LRW that came back came back whole but the partial ones and those after them (a
    // lost frame's row has no lrw_wkc), the ~2 000 of the break merged from both sides'
    // copies.
    let wkc = csv_column(&csv, "lrw_wkc");
    let not_whole = wkc.iter().filter(|&&w| w != 36.0).count() as u64;
    assert!(not_whole <= 2 * partial, "{not_whole} LRWs not whole");
    // Frames lost: this shared host's stalls only (a reply past its cycle's deadline: 2-10
    // in 9 000 cycles, with or without a ring, and 22 once in CI on a fresh machine); a
    // break sends each side's copy back by its own port and loses none. A ring that lost
    // what crossed the break would lose the 2 s of it, 2 000 frames: 1 % of the cycles
    // tells the two apart.
    let lost = j["lost_frames"].as_u64().unwrap();
    assert!(lost <= 90, "{lost} frames lost");
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
    let (mut served, judge_dir) = serve_ring(&pair, &ring_a, &dir, None);
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/pysoem/soem_cycle.py");
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
        // The phase gate before OP (200 cycles within this of the target) is SOEM's loop's,
        // not what is judged here: wide, so that a stall of this shared host does not stop it.
        .args(["--settle-us", "500"])
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
