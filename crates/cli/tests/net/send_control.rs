//! Issue 14, acceptance 3 and 4's refusal: send-time control on the real path.

use super::*;

/// Spinning and sleeping cycles side by side in one run over the veth pair (odd cycles
/// spin 50 us before their instant, even ones sleep to it): both measured on the same
/// host at the same moments; the ratio and the CPU the spinning cost are printed (a
/// figure of this host, not asserted: no timing is).
#[test]
#[ignore = "needs network namespaces (root)"]
fn spinning_and_sleeping_cycles_side_by_side_over_the_veth_pair() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let pair = NetPair::new("s");
    let _served = pair.serve(&[]);
    let o = pair
        .run(&[
            "--method",
            "median-fit",
            "--duration",
            "6",
            "--send",
            "spin",
            "--spin-margin-us",
            "50",
            "--spin-alternate",
            "--timeout-us",
            "100000",
            "--json",
        ])
        .output()
        .expect("run ecsync run");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let j: serde_json::Value = serde_json::from_slice(&o.stdout).expect("JSON summary");
    let s = &j["send"];
    assert_eq!(s["mode"], "spin", "{s}");
    assert_eq!(s["alternate"], true, "{s}");
    let cycles = j["cycles"].as_u64().unwrap();
    let (p, sp) = (&s["wake_to_send_plain"], &s["wake_to_send_spin"]);
    let (np, ns) = (p["n"].as_u64().unwrap(), sp["n"].as_u64().unwrap());
    // Half the cycles each (cycles a stall skipped are in neither).
    assert!(
        np + ns <= cycles && np + ns + cycles / 20 >= cycles,
        "{np} + {ns} of {cycles}"
    );
    assert!(np.abs_diff(ns) <= cycles / 20 + 2, "{np} against {ns}");
    let ratio = s["spin_over_plain_p99"].as_f64().expect("the ratio");
    assert!(ratio.is_finite() && ratio > 0.0, "{s}");
    let cpu = s["spin_cpu_pct"].as_f64().unwrap();
    assert!(cpu > 0.0 && cpu <= 100.0, "{s}");
    println!(
        "wake to send p99: sleeping {:.1} us, spinning {:.1} us (ratio {ratio:.3}); p99.9 {:.1} / {:.1} us; spinning cost {cpu:.2} % of a core, {:.1} us per spinning cycle",
        p["p99_us"].as_f64().unwrap(),
        sp["p99_us"].as_f64().unwrap(),
        p["p999_us"].as_f64().unwrap(),
        sp["p999_us"].as_f64().unwrap(),
        s["spin_us_per_cycle"].as_f64().unwrap()
    );
}

/// Independent truth for the refusal below: ethtool's own reading of the veth's driver (its
/// capabilities, the kernel's ETHTOOL_GET_TS_INFO answer): software transmit stamps, no
/// hardware ones, no PTP hardware clock.
#[test]
#[ignore = "needs network namespaces (root), ethtool"]
fn ethtool_shows_no_hardware_tx_stamps_on_the_veth() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let pair = NetPair::new("et");
    let o = Command::new("ip")
        .args(["netns", "exec", &pair.ns_b, "ethtool", "-T", &pair.if_b])
        .output()
        .expect("ip netns exec");
    let t = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "this test needs ethtool (apt-get install ethtool): {}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(t.contains("software-transmit"), "{t}");
    assert!(!t.contains("hardware-transmit"), "{t}");
    assert!(t.contains("PTP Hardware Clock: none"), "{t}");
}

/// A veth has no hardware transmit timestamps (see the test above): `--tx-stamp hardware` is
/// refused before anything is sent, naming what the driver lacks as `ethtool -T` reports it;
/// a transmit stamp for a bus-shift method is refused too (it writes its send time into the
/// frame before the frame leaves).
#[test]
#[ignore = "needs network namespaces (root)"]
fn hardware_tx_stamps_are_refused_on_veth_naming_what_is_missing() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let pair = NetPair::new("h");
    for (method, mode, want) in [
        ("median-fit", "hardware", "SOF_TIMESTAMPING_TX_HARDWARE"),
        ("median-fit", "hardware", "PTP Hardware Clock"),
        ("bus-shift", "software", "bus-shift method"),
        ("dcm-bus-shift", "hardware", "bus-shift method"),
    ] {
        let t0 = Instant::now();
        let o = pair
            .run(&["--method", method, "--tx-stamp", mode, "--duration", "2"])
            .output()
            .expect("run ecsync run");
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{method} {mode}: {err}");
        assert!(err.contains(want), "{method} {mode}: {err}");
        assert!(err.contains("fix:"), "{method} {mode}: {err}");
        let last = err.trim().lines().last().unwrap_or_default().to_string();
        assert!(
            last.starts_with("ecsync: error:"),
            "one clear line last: {err}"
        );
        // Refused before the bring-up (which takes seconds here).
        assert!(
            t0.elapsed().as_secs_f64() < 2.0,
            "{method} {mode}: {:?}",
            t0.elapsed()
        );
    }
}

/// This machine's kernel has no ETF qdisc: `--send txtime` is refused before anything is
/// sent, naming what is missing (the kernel option where the kernel says, else the
/// interface's qdisc and the command that adds it).
#[test]
#[ignore = "needs network namespaces (root)"]
fn txtime_is_refused_naming_the_missing_piece() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let pair = NetPair::new("t");
    let o = pair
        .run(&["--send", "txtime", "--duration", "2"])
        .output()
        .expect("run ecsync run");
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{err}");
    assert!(err.contains("ETF qdisc"), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "one clear line: {err}");
    let kernel_lacks_it = std::process::Command::new("sh")
        .args([
            "-c",
            "zcat /proc/config.gz | grep -q '# CONFIG_NET_SCH_ETF is not set'",
        ])
        .status()
        .is_ok_and(|s| s.success());
    if kernel_lacks_it {
        assert!(err.contains("CONFIG_NET_SCH_ETF is not set"), "{err}");
    } else {
        assert!(err.contains("tc qdisc"), "{err}");
    }
}
