//! ecsync on a real network: `ecsync serve` in one network namespace, a master in another, a
//! veth pair between them. The masters are `ecsync run` with each synchronization method, and
//! ethercrab (crates.io) on its own Linux raw-socket transport, plain and with ecsync's median
//! controller in its loop. The truth the masters are checked against is the preset's: the
//! propagation delays the virtual segment has by construction.
//!
//! The tests make their namespaces themselves with `ip netns`, which needs root (it mounts
//! the namespaces under /run/netns; an unprivileged user namespace cannot): each is
//! `#[ignore = "needs network namespaces (root)"]` (plus what else it needs), and asked for
//! (`cargo test -- --ignored`) on a machine that refuses, it fails naming why, never passes.
//! They run one at a time: each master pins a SCHED_FIFO task.
//!
//! Here: the namespaces and `ecsync serve`, and the tests of `ecsync run` itself (each method,
//! through faults and disturbances, the network twin), with their helpers in `checked_run`,
//! `disturb` and `twin`; the other masters (ethercrab, SOEM), single frames, the host stall
//! and send control in modules of their own.

use ecsync_sim::{Segment, preset};
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

// The helpers of the sim crate's tests: where the vendors' ESI files are, the shipped ESI.
#[path = "../../../sim/tests/common/mod.rs"]
mod common;
// The ring of issue 34 and its checks, as the sandbox test has them too.
#[path = "../common/ring.rs"]
mod ring_common;
// `ip`, as the lab's realnet test runs it.
#[path = "../../../lab/tests/common/ip.rs"]
mod ip;

mod checked_run;
mod control;
mod disturb;
mod esi_drives;
mod ethercrab_faults;
mod ethercrab_io;
mod ethercrab_raw;
mod host_stall;
mod raw_frames;
mod ring;
mod send_control;
mod soem;
mod twin;

use checked_run::run_method;
use disturb::{run_through_a_disturbance, run_through_faults};
use ip::ip;
use twin::{ranks_as_the_preset, true_relative_ppm};

static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

fn ecsync() -> &'static str {
    env!("CARGO_BIN_EXE_ecsync")
}

/// Two network namespaces joined by a veth pair; removed on drop.
struct NetPair {
    ns_a: String,
    ns_b: String,
    if_a: String,
    if_b: String,
}

impl NetPair {
    /// The pair, or a panic naming what the machine refused: the tests that make one are
    /// ignored unless asked for, and asked for they must not pass without it.
    fn new(tag: &str) -> NetPair {
        let id = std::process::id() % 100_000;
        let p = NetPair {
            ns_a: format!("ecs-{id}-{tag}-a"),
            ns_b: format!("ecs-{id}-{tag}-b"),
            if_a: format!("e{id}{tag}a"),
            if_b: format!("e{id}{tag}b"),
        };
        let setup = || -> Result<(), String> {
            ip(&["netns", "add", &p.ns_a])?;
            ip(&["netns", "add", &p.ns_b])?;
            ip(&[
                "link", "add", &p.if_a, "type", "veth", "peer", "name", &p.if_b,
            ])?;
            ip(&["link", "set", &p.if_a, "netns", &p.ns_a])?;
            ip(&["link", "set", &p.if_b, "netns", &p.ns_b])?;
            ip(&["-n", &p.ns_a, "link", "set", &p.if_a, "up"])?;
            ip(&["-n", &p.ns_b, "link", "set", &p.if_b, "up"])?;
            Ok(())
        };
        if let Err(e) = setup() {
            panic!(
                "this test needs network namespaces and a veth pair (root and iproute2), and this machine refused: {e}"
            );
        }
        p
    }

    /// A second veth pair between the namespaces (a ring's second master port and the
    /// segment's ring end): its ends in A and in B.
    fn second_pair(&self) -> (String, String) {
        let (a, b) = (format!("{}2", self.if_a), format!("{}2", self.if_b));
        let setup = || -> Result<(), String> {
            ip(&["link", "add", &a, "type", "veth", "peer", "name", &b])?;
            ip(&["link", "set", &a, "netns", &self.ns_a])?;
            ip(&["link", "set", &b, "netns", &self.ns_b])?;
            ip(&["-n", &self.ns_a, "link", "set", &a, "up"])?;
            ip(&["-n", &self.ns_b, "link", "set", &b, "up"])
        };
        if let Err(e) = setup() {
            panic!("this test needs a second veth pair, and this machine refused: {e}");
        }
        (a, b)
    }

    /// `ecsync args...` inside namespace `ns`.
    fn command(&self, ns: &str, args: &[&str]) -> Command {
        let mut c = Command::new("ip");
        c.args(["netns", "exec", ns, ecsync()]).args(args);
        c
    }

    /// `ecsync run --iface <B's end> args...` in namespace B.
    fn run(&self, args: &[&str]) -> Command {
        let mut c = self.command(&self.ns_b, &["run", "--iface", &self.if_b]);
        c.args(args);
        c
    }

    /// `ecsync run --iface <B's end> --csv csv args...` spawned (its output piped) and
    /// returned once the CSV holds 1 000 lines: the cyclic phase has run a second. A run that
    /// ends before is a failure showing what it said.
    fn spawn_run_until_a_second_of_cycles(&self, csv: &Path, args: &[&str]) -> Child {
        let mut run = self
            .run(&["--csv", csv.to_str().unwrap()])
            .args(args)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("spawn ecsync run");
        let t0 = Instant::now();
        while lines(csv) < 1_000 {
            if run.try_wait().expect("the run's status").is_some() {
                let o = run.wait_with_output().expect("the run's output");
                panic!(
                    "ecsync run ended ({}) before a second of cycles: {}",
                    o.status,
                    String::from_utf8_lossy(&o.stderr)
                );
            }
            assert!(
                t0.elapsed() < Duration::from_secs(30),
                "the cyclic phase did not start"
            );
            std::thread::sleep(Duration::from_millis(50));
        }
        run
    }

    /// `ecsync serve` on side A, once it is listening.
    fn serve(&self, extra: &[&str]) -> Served {
        let mut args = vec!["serve", "--iface", &self.if_a, "--quiet"];
        args.extend_from_slice(extra);
        let mut child = self
            .command(&self.ns_a, &args)
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .expect("spawn ecsync serve");
        let stderr = child.stderr.take().expect("stderr");
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            for line in BufReader::new(stderr).lines().map_while(Result::ok) {
                let _ = tx.send(line);
            }
        });
        let t0 = Instant::now();
        loop {
            match rx.recv_timeout(Duration::from_secs(10)) {
                Ok(l) if l.contains("Ctrl-C stops") => break,
                Ok(_) => {}
                Err(e) => panic!("ecsync serve did not start: {e}"),
            }
            assert!(t0.elapsed() < Duration::from_secs(10));
        }
        Served { child }
    }
}

impl Drop for NetPair {
    fn drop(&mut self) {
        let _ = ip(&["netns", "del", &self.ns_a]);
        let _ = ip(&["netns", "del", &self.ns_b]);
    }
}

struct Served {
    child: Child,
}

impl Served {
    fn kill(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Drop for Served {
    fn drop(&mut self) {
        self.kill();
    }
}

/// The preset's propagation delays from the reference (position 0), ns.
fn true_delays() -> Vec<f64> {
    let specs = ecsync_sim::config::parse_segment("paper-2024", preset::PAPER_2024_TOML).unwrap();
    let seg = Segment::new(&specs).unwrap();
    seg.true_delays_ns(0)
        .into_iter()
        .map(|d| d.expect("every drive has a delay"))
        .collect()
}

fn tmp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("ecsync-net-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn lines(p: &Path) -> usize {
    std::fs::read_to_string(p).map_or(0, |s| s.lines().count())
}

#[test]
#[ignore = "needs network namespaces (root)"]
fn serve_and_run_with_the_median_method() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let pair = NetPair::new("m");
    let _served = pair.serve(&[]);
    run_method(&pair, "median");
}

#[test]
#[ignore = "needs network namespaces (root)"]
fn serve_and_run_with_every_other_method() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let pair = NetPair::new("o");
    let _served = pair.serve(&[]);
    for m in [
        "median-fit",
        "pi-m2s",
        "bus-shift",
        "dcm-bus-shift",
        "snap",
        "soem-pi",
        "kickcat-pll",
        "igh-app-time",
        "linuxcnc-pll",
        "des",
        "kalman",
    ] {
        run_method(&pair, m);
    }
}

#[test]
#[ignore = "needs network namespaces (root)"]
fn every_method_runs_through_loss_a_reference_power_cycle_and_a_cable_pull_over_veth() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let pair = NetPair::new("f");
    let dir = tmp("faults");
    let faults = dir.join("faults.toml");
    std::fs::write(
        &faults,
        "[[fault]]\nat_s = 0\nkind = \"loss\"\nprobability = 0.1\n\n\
         [[fault]]\nat_s = 2\nfor_s = 0.2\nkind = \"power_cycle\"\nslave = \"reference\"\n\n\
         [[fault]]\nat_s = 5\nfor_s = 0.05\nkind = \"link_down\"\nslave = 1\nport = 0\n",
    )
    .unwrap();
    for m in [
        "median",
        "median-fit",
        "pi-m2s",
        "bus-shift",
        "dcm-bus-shift",
        "dcm-master-shift",
        "snap",
        "soem-pi",
    ] {
        run_through_faults(&pair, m, &faults);
    }
}

#[test]
#[ignore = "needs network namespaces (root)"]
fn serve_and_run_survive_their_interfaces_going_down_for_50_ms() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let pair = NetPair::new("d");
    let j = run_through_a_disturbance(&pair, "down", || {
        // The segment's interface down for 50 ms, then the master's.
        for (ns, ifc) in [(&pair.ns_a, &pair.if_a), (&pair.ns_b, &pair.if_b)] {
            ip(&["-n", ns, "link", "set", ifc, "down"]).unwrap();
            std::thread::sleep(Duration::from_millis(50));
            ip(&["-n", ns, "link", "set", ifc, "up"]).unwrap();
            std::thread::sleep(Duration::from_millis(1_000));
        }
    });
    let lost = j["lost_frames"].as_u64().unwrap();
    println!(
        "interfaces down: {lost} frames lost, the master's interface refused {} times",
        j["link_down_errors"]
    );
    // Two outages of 50 ms (and the time a veth takes to carry again).
    assert!((50..2_000).contains(&lost), "{lost} frames lost");
}

/// The master's interface stalled for 400 ms, then the served segment's (a token bucket of
/// 8 kbit/s holds the frames, as a congested or stalled NIC queue does): once the socket's send
/// queue is full, each frame it cannot take is a lost frame, not the end of the run or of
/// serving (the fresh-clone CI once saw a run stop with "the socket's send queue stayed full"
/// when an interface came back up).
#[test]
#[ignore = "needs network namespaces (root)"]
fn run_survives_a_send_queue_that_stays_full() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let pair = NetPair::new("q");
    let tc = |ns: &str, args: &[&str]| {
        let o = Command::new("tc")
            .args(["-n", ns, "qdisc"])
            .args(args)
            .output()
            .expect("tc (iproute2)");
        assert!(
            o.status.success(),
            "tc qdisc {}: {}",
            args.join(" "),
            String::from_utf8_lossy(&o.stderr)
        );
    };
    let j = run_through_a_disturbance(&pair, "queue", || {
        // The master's queue, then the served segment's.
        for (ns, ifc) in [(&pair.ns_b, &pair.if_b), (&pair.ns_a, &pair.if_a)] {
            tc(
                ns,
                &[
                    "replace", "dev", ifc, "root", "tbf", "rate", "8kbit", "burst", "1600",
                    "limit", "10000000",
                ],
            );
            std::thread::sleep(Duration::from_millis(400));
            tc(ns, &["del", "dev", ifc, "root"]);
            std::thread::sleep(Duration::from_millis(1_000));
        }
    });
    let lost = j["lost_frames"].as_u64().unwrap();
    let refused = j["link_down_errors"].as_u64().unwrap();
    println!(
        "interfaces stalled for 400 ms each: {lost} frames lost, the master's interface refused {refused} sends"
    );
    // The socket's queue (212 992 bytes by default, about 1.3 KiB of it a small frame) fills
    // after some 170 cycles, and refuses from then on.
    assert!(refused > 0, "no send was refused: the queue never filled");
    assert!((50..2_000).contains(&lost), "{lost} frames lost");
}

#[test]
#[ignore = "needs network namespaces (root)"]
fn a_segment_that_dies_mid_run_is_reported_and_what_was_measured_is_kept() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let pair = NetPair::new("k");
    let mut served = pair.serve(&[]);
    let dir = tmp("kill");
    let csv = dir.join("cycles.csv");
    let summary = dir.join("summary.json");
    let t0 = Instant::now();
    // Kill the segment once the cyclic phase has run a second.
    let run = pair.spawn_run_until_a_second_of_cycles(
        &csv,
        &[
            "--duration",
            "30",
            // Without it the run keeps trying (and recovers a segment that comes back).
            "--give-up-after",
            "100",
            "--summary",
            summary.to_str().unwrap(),
        ],
    );
    served.kill();
    let o = run.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(3), "exit status; stderr: {stderr}");
    assert!(
        stderr.contains("stopped answering") && !stderr.contains("panicked"),
        "{stderr}"
    );
    let j: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&summary).unwrap()).unwrap();
    assert_eq!(j["stopped"], "network-gone");
    let lost = j["lost_frames"].as_u64().unwrap();
    assert!(lost >= 100, "lost frames reported: {lost}");
    let cycles = j["cycles"].as_u64().unwrap();
    assert!(cycles >= 1_000);
    assert_eq!(
        lines(&csv),
        cycles as usize + 1,
        "the CSV holds every cycle run"
    );
    assert!(t0.elapsed() < Duration::from_secs(25), "gave up in time");
}

#[test]
fn a_missing_interface_is_one_clear_line() {
    for sub in [
        &["run", "--iface", "ecsnosuch0", "--duration", "1"][..],
        &["serve", "--iface", "ecsnosuch0"][..],
    ] {
        let o = Command::new(ecsync()).args(sub).output().unwrap();
        let e = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success());
        assert!(
            e.contains("ecsnosuch0 does not exist") && !e.contains("panicked"),
            "{e}"
        );
        assert_eq!(
            e.lines().filter(|l| !l.contains("warning")).count(),
            1,
            "{e}"
        );
    }
}

/// Two serves on one interface would both answer every frame (a master sees two segments'
/// replies): the second is refused, naming the interface, the first's pid and the fix, and
/// the first serves on. (Before, the second served beside it without a word.)
#[test]
#[ignore = "needs network namespaces (root)"]
fn a_second_serve_on_an_interface_is_refused_naming_the_first() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let pair = NetPair::new("ss");
    let mut first = pair.serve(&[]);
    // `ip netns exec` execs ecsync: the child's pid is serve's.
    let pid = first.child.id();
    let mut second = pair
        .command(&pair.ns_a, &["serve", "--iface", &pair.if_a, "--quiet"])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn the second serve");
    // A limit against a second serve that serves on (as it did), not a timing.
    let t0 = Instant::now();
    let status = loop {
        if let Some(s) = second.try_wait().unwrap() {
            break Some(s);
        }
        if t0.elapsed() > Duration::from_secs(30) {
            let _ = second.kill();
            let _ = second.wait();
            break None;
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let mut e = String::new();
    std::io::Read::read_to_string(&mut second.stderr.take().unwrap(), &mut e).unwrap();
    let status = status.unwrap_or_else(|| panic!("the second serve served on: {e}"));
    assert!(!status.success(), "{e}");
    assert!(
        e.contains(&format!("--iface {}", pair.if_a))
            && e.contains(&format!("pid {pid}"))
            && e.contains("fix: stop that serve"),
        "{e}"
    );
    assert!(
        first.child.try_wait().unwrap().is_none(),
        "the first serve ended"
    );
    // Once the first has ended, its interface is free again.
    first.kill();
    let third = pair.serve(&[]);
    drop(third);
}

/// A serve killed with SIGKILL leaves its lock file, unlocked: the next serve on the interface
/// takes it over without a word (its own pid in it), and removes the folder's other unlocked
/// lock files (a killed serve's in a namespace that is gone: before, one stayed for each, and
/// /run/ecsync filled with them), not one another process holds.
#[test]
#[ignore = "needs network namespaces (root)"]
fn a_serve_killed_with_sigkill_leaves_a_lock_the_next_takes_and_stale_ones_are_removed() {
    use std::os::fd::AsRawFd;
    use std::os::unix::fs::MetadataExt;
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let pair = NetPair::new("k");
    // Root's lock folder; the file is named after the namespace's inode and the interface.
    let dir = Path::new("/run/ecsync");
    let netns = std::fs::metadata(format!("/run/netns/{}", pair.ns_a))
        .unwrap()
        .ino();
    let lock = dir.join(format!("serve-net{netns}-{}.lock", pair.if_a));
    let mut first = pair.serve(&[]);
    let pid = first.child.id();
    assert_eq!(std::fs::read_to_string(&lock).unwrap(), pid.to_string());
    // `Served::kill` is SIGKILL: serve removes nothing.
    first.kill();
    assert_eq!(std::fs::read_to_string(&lock).unwrap(), pid.to_string());
    // A dead serve's file of an interface in a namespace that is gone (pid 0: nobody), and one
    // this test holds locked as a live serve would.
    let id = std::process::id();
    let stale = dir.join(format!("serve-net1-stale{id}.lock"));
    let held = dir.join(format!("serve-net1-held{id}.lock"));
    std::fs::write(&stale, "0").unwrap();
    std::fs::write(&held, "0").unwrap();
    let held_file = std::fs::File::open(&held).unwrap();
    // SAFETY: plain FFI call on a descriptor the File owns and keeps open.
    let r = unsafe { libc::flock(held_file.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) };
    assert_eq!(r, 0);
    // `serve` panics unless the next serve starts serving.
    let second = pair.serve(&[]);
    let second_pid = second.child.id();
    let now = std::fs::read_to_string(&lock).unwrap();
    let (stale_left, held_left) = (stale.exists(), held.exists());
    let _ = std::fs::remove_file(&stale);
    drop(held_file);
    let _ = std::fs::remove_file(&held);
    assert_eq!(now, second_pid.to_string());
    assert!(
        !stale_left,
        "the stale lock file {} is still there",
        stale.display()
    );
    assert!(
        held_left,
        "a locked lock file {} was removed",
        held.display()
    );
    drop(second);
}

/// Root without CAP_NET_RAW (dropped from the bounding set by setpriv, util-linux).
#[test]
#[ignore = "needs network namespaces (root), setpriv"]
fn no_raw_socket_permission_is_one_clear_line() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let pair = NetPair::new("p");
    let probe = Command::new("setpriv").arg("--version").output();
    assert!(
        probe.is_ok_and(|o| o.status.success()),
        "this test needs setpriv (util-linux)"
    );
    for sub in [
        &["run", "--iface", pair.if_b.as_str(), "--duration", "1"][..],
        &["serve", "--iface", pair.if_b.as_str()][..],
    ] {
        let o = Command::new("ip")
            .args([
                "netns",
                "exec",
                &pair.ns_b,
                "setpriv",
                "--bounding-set=-net_raw",
            ])
            .arg(ecsync())
            .args(sub)
            .output()
            .unwrap();
        let e = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{sub:?} succeeded without CAP_NET_RAW");
        assert!(
            e.contains("needs CAP_NET_RAW") && !e.contains("panicked"),
            "{e}"
        );
        assert_eq!(
            e.lines().filter(|l| !l.contains("warning")).count(),
            1,
            "{e}"
        );
    }
}

/// Issue 14's first acceptance: `run --scan-only --save-network` against `serve --preset
/// paper-2024` writes a twin on which `bringup` finds every delay within 20 ns and every crystal
/// against the reference within 0.1 ppm of the preset's truth, and `compare` ranks the methods
/// as on the preset (same host, seed, run and method tables).
#[test]
#[ignore = "needs network namespaces (root)"]
fn a_twin_saved_over_veth_has_the_preset_s_delays_crystals_and_ranking() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let pair = NetPair::new("tw");
    let dir = tmp("twin");
    let twin = dir.join("twin.toml");
    {
        let _served = pair.serve(&[]);
        let o = pair
            .run(&[
                "--scan-only",
                "--save-network",
                twin.to_str().unwrap(),
                // The reference's crystal against true time cannot be measured here (the
                // segment's true time is this host's clock, the master's own, and the
                // figure measured against it is ~10 ppm off, see the report); the preset's
                // is given, the others are the twin's measurement against it.
                "--reference-ppm",
                "12.4",
            ])
            .output()
            .expect("run ecsync run --scan-only");
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.success(), "ecsync run --scan-only: {stderr}");
        eprintln!("{}", stderr.trim());
    }
    let text = std::fs::read_to_string(&twin).expect("the twin is written");
    let specs = ecsync_sim::config::parse_segment("twin.toml", &text)
        .unwrap_or_else(|e| panic!("the twin does not parse: {e}\n{text}"));
    assert_eq!(specs.len(), 6, "{text}");
    for s in &specs {
        assert_eq!(s.model, ecsync_sim::model::EscModel::servo_mii(), "{text}");
    }

    // bringup on the twin: its true and measured delays, its crystals.
    let o = Command::new(ecsync())
        .args([
            "bringup",
            "--config",
            twin.to_str().unwrap(),
            "--json",
            "--rate-window-s",
            "2",
            "--static-drift",
            "2000",
            "--monitor-cycles",
            "10",
        ])
        .output()
        .expect("run ecsync bringup");
    assert!(
        o.status.success(),
        "bringup --config twin: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let j: serde_json::Value = serde_json::from_slice(&o.stdout).expect("bringup JSON");
    let slaves = j["slaves"].as_array().expect("slaves");
    let (truth, truth_ppm) = (true_delays(), true_relative_ppm());
    assert_eq!(slaves.len(), truth.len());
    let (mut worst_true_ns, mut worst_measured_ns, mut worst_ppm) = (0.0f64, 0.0f64, 0.0f64);
    for (k, s) in slaves.iter().enumerate() {
        let twin_true = s["true_delay_ns"].as_f64().expect("a true delay");
        let twin_measured = s["delay_ns"].as_f64().expect("a measured delay");
        let ppm = s["true_ppm_vs_reference"].as_f64().expect("a crystal");
        worst_true_ns = worst_true_ns.max((twin_true - truth[k]).abs());
        worst_measured_ns = worst_measured_ns.max((twin_measured - truth[k]).abs());
        worst_ppm = worst_ppm.max((ppm - truth_ppm[k]).abs());
        assert!(
            (twin_true - truth[k]).abs() <= 20.0 && (twin_measured - truth[k]).abs() <= 20.0,
            "slave {k}: the twin's delay is {twin_true:.1} ns (bringup measures {twin_measured:.1}), the preset's {:.1}\n{text}",
            truth[k]
        );
        assert!(
            (ppm - truth_ppm[k]).abs() <= 0.1,
            "slave {k}: the twin's crystal is {ppm:+.4} ppm against the reference, the preset's {:+.4}\n{text}",
            truth_ppm[k]
        );
    }
    eprintln!(
        "twin over veth: worst delay error {worst_true_ns:.1} ns (the twin's truth), {worst_measured_ns:.1} ns (bringup's measurement on it), worst crystal error against the reference {worst_ppm:.4} ppm"
    );

    // compare: the twin's segment with the preset's host, run and methods, against the preset.
    ranks_as_the_preset(&text, &dir);
}

/// A twin saved by a run (not a scan): the reference's crystal against this host's clock comes
/// from the cyclic phase (the reference's time against the send stamps over 12 s of cycles),
/// not from the bring-up's 2 s of latches, and lands near the preset's 12.4 ppm without
/// `--reference-ppm`; every other crystal still within 0.1 ppm of the preset's against it.
#[test]
#[ignore = "needs network namespaces (root)"]
fn a_twin_saved_after_a_run_has_the_reference_crystal_from_the_cyclic_phase() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let pair = NetPair::new("tr");
    let dir = tmp("twin-run");
    let twin = dir.join("twin.toml");
    let _served = pair.serve(&[]);
    let o = pair
        .run(&[
            "--method",
            "median-fit",
            "--duration",
            "12",
            "--timeout-us",
            "100000",
            "--save-network",
            twin.to_str().unwrap(),
            "--json",
        ])
        .output()
        .expect("run ecsync run");
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(
        err.contains("over") && err.contains("cycles of the run"),
        "{err}"
    );
    let text = std::fs::read_to_string(&twin).unwrap();
    let specs = ecsync_sim::config::parse_segment(twin.to_str().unwrap(), &text).unwrap();
    let truth = ecsync_sim::config::parse_segment("paper-2024", preset::PAPER_2024_TOML).unwrap();
    let (got, want) = (specs[0].crystal.ppm, truth[0].crystal.ppm);
    println!("twin after a run: reference {got:+.3} ppm against this host, preset {want:+.3} ppm");
    // The preset's crystals wander (0.005 ppm/sqrt(s) and its host's send stamps jitter by tens
    // of microseconds): 1 ppm is ten times what 12 s of cycles resolve here.
    assert!(
        (got - want).abs() < 1.0,
        "reference {got} ppm, preset {want} ppm"
    );
    let rel = true_relative_ppm();
    for (k, s) in specs.iter().enumerate() {
        let r = ((1.0 + s.crystal.ppm * 1e-6) / (1.0 + got * 1e-6) - 1.0) * 1e6;
        assert!(
            (r - rel[k]).abs() < 0.1,
            "slave {k}: {r} ppm against {}",
            rel[k]
        );
    }
    // And with nothing told: compare ranks the methods on the twin as on the preset.
    ranks_as_the_preset(&text, &dir);
}
