//! ecsync on a real network: `ecsync serve` in one network namespace, a master in another, a
//! veth pair between them. The masters are `ecsync run` with each synchronization method, and
//! ethercrab (crates.io) on its own Linux raw-socket transport, plain and with ecsync's median
//! controller in its loop. The truth the masters are checked against is the preset's: the
//! propagation delays the virtual segment has by construction.
//!
//! The tests make their namespaces themselves and skip, saying why, only where the machine
//! refuses to (no root, no `ip`). They run one at a time: each master pins a SCHED_FIFO task.

use ecsync_sim::{Segment, preset};
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

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

fn ip(args: &[&str]) -> Result<(), String> {
    let o = Command::new("ip")
        .args(args)
        .output()
        .map_err(|e| format!("ip: {e}"))?;
    if o.status.success() {
        Ok(())
    } else {
        Err(format!(
            "ip {}: {}",
            args.join(" "),
            String::from_utf8_lossy(&o.stderr).trim()
        ))
    }
}

impl NetPair {
    /// The pair, or `None` (after printing why) where the machine refuses.
    fn new(tag: &str) -> Option<NetPair> {
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
        match setup() {
            Ok(()) => Some(p),
            Err(e) => {
                // CI runs as root on a machine that has them: there a refusal is a failure.
                assert!(
                    std::env::var_os("CI").is_none(),
                    "CI must be able to make network namespaces and veth pairs: {e}"
                );
                println!("SKIPPED: this machine refuses network namespaces and veth pairs ({e})");
                None
            }
        }
    }

    /// `ecsync args...` inside namespace `ns`.
    fn command(&self, ns: &str, args: &[&str]) -> Command {
        let mut c = Command::new("ip");
        c.args(["netns", "exec", ns, ecsync()]).args(args);
        c
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

thread_local! {
    /// The wake-up p99 of the last `ecsync run` of this thread, us.
    static LAST_WAKE_P99_US: std::cell::Cell<f64> = const { std::cell::Cell::new(f64::NAN) };
}

/// A wake-up p99 past this says the host, not the path, was in trouble: this shared VM has
/// phases in which an idle guest's 1 ms timer wakes a millisecond late one cycle in a hundred
/// (its quiet p99 is 80-150 us), and `serve`'s segment, which runs on the same cores in real
/// time, then takes its frames late as well.
const NOISY_HOST_P99_US: f64 = 400.0;

/// `ecsync run` with `method` for 10 s at 1 ms against `ecsync serve`, checked; once more if
/// the checks failed while the host was noisy (see [`NOISY_HOST_P99_US`]), and the second run
/// must pass them all.
fn run_method(pair: &NetPair, method: &str) {
    LAST_WAKE_P99_US.with(|c| c.set(f64::NAN));
    let first = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        run_method_once(pair, method);
    }));
    if let Err(e) = first {
        let p99 = LAST_WAKE_P99_US.with(|c| c.get());
        if p99 > NOISY_HOST_P99_US {
            println!(
                "{method}: the checks failed with the host's wake-up p99 at {p99:.0} us (noisy): once more"
            );
            run_method_once(pair, method);
        } else {
            std::panic::resume_unwind(e);
        }
    }
}

/// The values of column `name` of a `run --csv` file, rows with it blank left out.
fn csv_column(csv: &Path, name: &str) -> Vec<f64> {
    let text = std::fs::read_to_string(csv).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let c = header
        .iter()
        .position(|c| *c == name)
        .unwrap_or_else(|| panic!("no column {name} in {}", csv.display()));
    lines
        .filter_map(|l| l.split(',').nth(c)?.parse().ok())
        .collect()
}

fn run_method_once(pair: &NetPair, method: &str) {
    let dir = tmp(method);
    let csv = dir.join("cycles.csv");
    let t0 = Instant::now();
    let o = pair
        .command(
            &pair.ns_b,
            &[
                "run",
                "--iface",
                &pair.if_b,
                "--method",
                method,
                "--cycle-us",
                "1000",
                "--duration",
                "10",
                // A reply held up by a stall of this shared host is late, not lost: the test
                // asks whether the path loses frames, and counts the late ones apart.
                "--timeout-us",
                "100000",
                "--csv",
                csv.to_str().unwrap(),
                "--json",
            ],
        )
        .output()
        .expect("run ecsync run");
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "ecsync run --method {method}: {stderr}");
    let j: serde_json::Value = serde_json::from_slice(&o.stdout).expect("JSON summary");
    let p99 = j["wake_latency"]["p99_us"].as_f64().unwrap_or(f64::NAN);
    LAST_WAKE_P99_US.with(|c| c.set(p99));
    let b = &j["bringup"];
    // Every slave found, delays within 20 ns of the preset's.
    let truth = true_delays();
    let slaves = b["slaves"].as_array().unwrap();
    assert_eq!(slaves.len(), truth.len(), "{method}: every slave found");
    for (s, t) in slaves.iter().zip(&truth) {
        let d = s["delay_ns"].as_f64().expect("delay");
        assert!(
            (d - t).abs() <= 20.0,
            "{method}: slave {} delay {d:.1} ns, preset {t:.1} ns",
            s["position"]
        );
    }
    // DC in sync: locked in the bring-up and |0x092C| small all through the cyclic phase.
    assert_eq!(b["converged"], true, "{method}: DC locked");
    assert!(b["max_abs_092c_after_lock_ns"].as_u64().unwrap() < 100);
    let rs_is = &j["rs_is"];
    if method == "bus-shift" {
        // The master's time is written to the reference every cycle: the reference's 0x092C
        // (and so the BRD, which ORs every slave's) shows how far the master's timestamp is
        // from the frame's arrival, i.e. this host's send jitter, which no threshold bounds on
        // a shared machine (the letter's large rS-IS error of E-S2M). In sync means following:
        // the reference follows the master (t_ra - t_ms has no trend: a reference left alone
        // drifts at the preset's 12.4 ppm, 124 us in 10 s; 3 ppm is the bound) and the slaves follow the
        // reference (|0x092C| stays at the jitter's microseconds). Medians over windows: a
        // host stall between timestamp and send is an outlier, not a loss of sync.
        let text = std::fs::read_to_string(&csv).unwrap();
        let header: Vec<&str> = text.lines().next().unwrap().split(',').collect();
        let col = |name: &str| header.iter().position(|c| *c == name).unwrap();
        let (c_send, c_err, c_092c) = (col("send_ns"), col("error_ns"), col("max_abs_092c_ns"));
        let rows: Vec<Vec<f64>> = text
            .lines()
            .skip(1)
            .map(|l| {
                l.split(',')
                    .map(|x| x.parse().unwrap_or(f64::NAN))
                    .collect()
            })
            .collect();
        let median = |mut v: Vec<f64>| {
            v.retain(|x| x.is_finite());
            v.sort_by(f64::total_cmp);
            v[v.len() / 2]
        };
        // From the second fifth of the run to the last: the reference starts the cyclic phase
        // off by what it drifted during the bring-up and its loop takes seconds to settle.
        let fifth = rows.len() / 5;
        let (head, tail) = (&rows[fifth..2 * fifth], &rows[rows.len() - fifth..]);
        let mid_time = |w: &[Vec<f64>]| median(w.iter().map(|r| r[c_send]).collect());
        let mid_err = |w: &[Vec<f64>]| median(w.iter().map(|r| r[c_err]).collect());
        let drift_ppm = (mid_err(tail) - mid_err(head)) / (mid_time(tail) - mid_time(head)) * 1e6;
        let err_abs = median(rows.iter().map(|r| r[c_err].abs()).collect());
        let diff_abs = median(rows.iter().map(|r| r[c_092c]).collect());
        println!(
            "bus-shift: reference vs master drift {drift_ppm:.3} ppm, median |t_ra - t_ms| {err_abs:.0} ns, median |0x092C| {diff_abs:.0} ns"
        );
        assert!(
            drift_ppm.abs() < 3.0,
            "bus-shift: the reference drifts from the master by {drift_ppm:.2} ppm"
        );
        assert!(
            err_abs < 20_000.0,
            "bus-shift: median |t_ra - t_ms| {err_abs} ns"
        );
        assert!(
            diff_abs < 10_000.0,
            "bus-shift: median |0x092C| {diff_abs} ns"
        );
    } else {
        // The lock threshold (100 ns) in 99% of the cycles, never beyond a microsecond. (The
        // frames come at the host's irregular instants and every compare meets the MII ports'
        // 40 ns receive clock at another phase: single cycles show 80-120 ns.) DCM's bus shift
        // moves the reference's time while it pulls in (10 s here, from the tens of
        // microseconds the host's send latency puts the first frames off), which the slaves
        // follow within a hundred ns or so: twice the threshold.
        let p99_bound = if method == "dcm-bus-shift" {
            200.0
        } else {
            100.0
        };
        assert!(
            rs_is["p99_abs"].as_f64().unwrap() <= p99_bound,
            "{method}: {rs_is}"
        );
        if method == "dcm-bus-shift" {
            let c = &j["controller"];
            assert!(c["drift_ppm"].as_f64().unwrap().abs() < 100.0, "{c}");
        }
        assert!(
            rs_is["max"].as_f64().unwrap() < 1_000.0,
            "{method}: {rs_is}"
        );
    }
    // The whole run, every cycle in the CSV, nothing lost.
    // Cycles whose slots a host stall took are skipped, not sent in a burst.
    let cycles = j["cycles"].as_u64().unwrap();
    let skipped = j["skipped_cycles"].as_u64().unwrap();
    assert!(
        (9_500..=10_500).contains(&(cycles + skipped)),
        "{method}: {cycles} cycles and {skipped} skipped in 10 s"
    );
    assert_eq!(
        lines(&csv),
        cycles as usize + 1,
        "{method}: one CSV row per cycle"
    );
    // Nothing is lost on a veth pair; a reply the busy host took longer than a cycle to read
    // is discarded as late (and is a lost frame): its cycle only. How many replies come late
    // is this host's timing, not the path's (this shared two-core VM has made 3.7 % of a run's
    // replies late in CI, with a wake-up p99 of 1 ms): the test checks that every lost frame
    // is a late reply, and that most cycles are answered (a path that loses frames, or
    // answers one cycle in two, fails both).
    let lost = j["lost_frames"].as_u64().unwrap();
    let late = j["link"]["late"].as_u64().unwrap();
    println!(
        "{method}: {lost} lost, {late} late of {cycles} (wake-up p99 {:.1} us)",
        j["wake_latency"]["p99_us"].as_f64().unwrap_or(f64::NAN)
    );
    assert!(
        lost <= late + 1 && lost * 5 < cycles,
        "{method}: {lost} frames lost, {late} replies late"
    );
    assert_eq!(j["bad_wkc"], 0, "{method}: working counters");
    // t_ms under `--tx-stamp auto` (the default): a master-shift method takes the kernel's
    // software transmit stamp of the cycle's frame (a veth has no hardware stamps: the note
    // names what it lacks), every answered cycle but a rare one whose stamp had not come; a
    // bus-shift method its send timestamp, which goes into the frame before it leaves.
    let t = &j["t_ms"];
    let answered = cycles - lost;
    let (stamped, unstamped) = (
        t["cycles_from_tx_stamp"].as_u64().unwrap(),
        t["cycles_without_tx_stamp"].as_u64().unwrap(),
    );
    if method.ends_with("bus-shift") {
        assert_eq!(t["source"], "send_timestamp", "{method}: {t}");
        assert_eq!((stamped, unstamped), (0, 0), "{method}: {t}");
    } else {
        assert_eq!(t["source"], "kernel_software", "{method}: {t}");
        let note = t["note"].as_str().unwrap_or_default();
        assert!(
            note.contains("no hardware transmit timestamps"),
            "{method}: {t}"
        );
        assert!(
            stamped + unstamped <= answered && stamped + unstamped + 2 >= answered,
            "{method}: {stamped} + {unstamped} of {answered} answered cycles"
        );
        assert!(unstamped * 100 <= answered, "{method}: {t}");
        // The kernel stamps the frame after the send timestamp, never before.
        let delays = csv_column(&csv, "tx_delay_ns");
        assert!(
            delays.len() as u64 + 2 >= stamped,
            "{method}: {} delays",
            delays.len()
        );
        // (Up to the error of the kernel stamp's conversion from the wall clock: its
        // difference to the monotonic clock is read between two reads of the latter. On a
        // veth pair the stamp comes ~1 us after the send, and a CI run once saw one before.)
        let slack_ns = ecsync_net::wall_clock::CONVERSION_ERROR_NS as f64;
        let earliest = delays.iter().copied().fold(f64::INFINITY, f64::min);
        assert!(
            earliest >= -slack_ns,
            "{method}: a stamp {earliest} ns before its send"
        );
    }
    // Every drive's SM-event-missed counter read over CoE in the cyclic phase, once a second:
    // the last read in the run's last two seconds.
    let counters = j["sm_events_missed"].as_array().unwrap();
    let positions: Vec<u64> = counters
        .iter()
        .map(|c| c["position"].as_u64().unwrap())
        .collect();
    assert_eq!(positions, [1, 2, 3, 4, 5, 6], "{method}: {counters:?}");
    for c in counters {
        assert!(
            c["read_s"].as_f64().unwrap() >= 8.0,
            "{method}: read too early {c}"
        );
    }
    assert!(
        j["m_rs"]["n"].as_u64().unwrap() > 5_000,
        "{method}: M-rS measured"
    );
    let missed: Vec<&serde_json::Value> = counters
        .iter()
        .map(|c| &c["missed_between_reads"])
        .collect();
    println!(
        "{method}: {cycles} cycles in {:.1} s ({lost} lost, {late} late); M-rS std {:.0} ns, rS-IS max {} ns; wake-up p99 {:.1} us; SM events missed between the reads {missed:?}",
        t0.elapsed().as_secs_f64(),
        j["m_rs"]["std"].as_f64().unwrap(),
        rs_is["max"],
        j["wake_latency"]["p99_us"].as_f64().unwrap()
    );
}

#[test]
fn serve_and_run_with_the_median_method() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let Some(pair) = NetPair::new("m") else {
        return;
    };
    let _served = pair.serve(&[]);
    run_method(&pair, "median");
}

#[test]
fn serve_and_run_with_every_other_method() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let Some(pair) = NetPair::new("o") else {
        return;
    };
    let _served = pair.serve(&[]);
    for m in [
        "median-fit",
        "pi-m2s",
        "bus-shift",
        "dcm-bus-shift",
        "snap",
        "soem-pi",
    ] {
        run_method(&pair, m);
    }
}

/// `ecsync run` with `method` for 8 s against `ecsync serve --faults`: 10 % loss all through
/// the cyclic phase, the reference switched off for 200 ms at 2 s, the master's cable pulled
/// for 50 ms at 5 s. The run keeps going, brings the reference back and ends locked.
fn run_through_faults(pair: &NetPair, method: &str, faults: &Path) {
    let _served = pair.serve(&["--faults", faults.to_str().unwrap()]);
    let dir = tmp(&format!("faults-{method}"));
    let csv = dir.join("cycles.csv");
    let o = pair
        .command(
            &pair.ns_b,
            &[
                "run",
                "--iface",
                &pair.if_b,
                "--method",
                method,
                "--duration",
                "8",
                "--static-drift",
                "3000",
                "--csv",
                csv.to_str().unwrap(),
                "--json",
            ],
        )
        .output()
        .expect("run ecsync run");
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{method}: {stderr}");
    let j: serde_json::Value = serde_json::from_slice(&o.stdout).expect("JSON summary");
    assert_eq!(j["stopped"], "duration", "{method}: ran to its end");
    let cycles = j["cycles"].as_u64().unwrap() as f64;
    let lost = j["lost_frames"].as_u64().unwrap() as f64;
    // 10 % of the cycles, the 200 ms off and the 50 ms unplugged, and what the busy host adds.
    assert!(
        lost > 0.07 * cycles && lost < 0.16 * cycles + 300.0,
        "{method}: {lost} of {cycles} cycles lost"
    );
    let back: Vec<&serde_json::Value> = j["recoveries"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|r| r["slaves"].as_array().is_some_and(|s| !s.is_empty()))
        .collect();
    // The reference reset; the drives behind it left OP on their watchdogs (200 ms without
    // outputs) and came back with it, as their AL status said.
    assert!(
        back.iter().any(|r| {
            let left: Vec<&str> = r["left_op"]
                .as_array()
                .map(|a| a.iter().filter_map(|x| x.as_str()).collect())
                .unwrap_or_default();
            r["slaves"] == serde_json::json!([1, 2, 3, 4, 5, 6])
                && left.len() == 5
                && left.iter().all(|l| l.contains("0x001b"))
        }),
        "{method}: the reference brought back: {}",
        j["recoveries"]
    );
    // Locked again at the end: the last second's |0x092C| of the cycles that came back.
    let tail = csv_column(&csv, "max_abs_092c_ns");
    let mut last: Vec<f64> = tail[tail.len().saturating_sub(900)..].to_vec();
    last.sort_by(f64::total_cmp);
    let worst = last.last().copied().unwrap_or(f64::NAN);
    let median = last[last.len() / 2];
    println!(
        "{method}: {lost} of {cycles} cycles lost, recoveries {}, last second's |0x092C| median {median} ns, max {worst} ns",
        j["recoveries"]
    );
    if method == "bus-shift" {
        // The master's timestamp is written to the reference every cycle, so |0x092C| shows
        // this host's send jitter, which no threshold bounds on a shared machine (see
        // run_method; a noisy phase of this VM gave a 219 us single cycle). Following means
        // medians at the jitter's microseconds: the slaves follow the reference (|0x092C|)
        // and the reference, whose time its power cycle reset, follows the master again
        // (|t_ra - t_ms|).
        assert!(
            median < 10_000.0,
            "{method}: median |0x092C| {median} ns in the last second"
        );
        let mut err: Vec<f64> = csv_column(&csv, "error_ns")
            .into_iter()
            .map(f64::abs)
            .collect();
        err = err.split_off(err.len().saturating_sub(900));
        err.sort_by(f64::total_cmp);
        let err_median = err[err.len() / 2];
        assert!(
            err_median < 20_000.0,
            "{method}: median |t_ra - t_ms| {err_median} ns in the last second"
        );
    } else {
        assert!(
            worst < 1_000.0,
            "{method}: |0x092C| {worst} ns in the last second"
        );
    }
}

#[test]
fn every_method_runs_through_loss_a_reference_power_cycle_and_a_cable_pull_over_veth() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let Some(pair) = NetPair::new("f") else {
        return;
    };
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

/// Serves a segment and runs `median` against it for 6 s, calling `disturb` once the cyclic
/// phase has run 1 000 cycles; checks that both came through it (the run stopped by its
/// duration, serve still there, locked at the end) and returns the run's summary.
fn run_through_a_disturbance(
    pair: &NetPair,
    name: &str,
    disturb: impl FnOnce(),
) -> serde_json::Value {
    let mut served = pair.serve(&[]);
    let dir = tmp(name);
    let csv = dir.join("cycles.csv");
    let summary = dir.join("summary.json");
    let run = pair
        .command(
            &pair.ns_b,
            &[
                "run",
                "--iface",
                &pair.if_b,
                "--duration",
                "6",
                "--csv",
                csv.to_str().unwrap(),
                "--summary",
                summary.to_str().unwrap(),
            ],
        )
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let t0 = Instant::now();
    while lines(&csv) < 1_000 {
        assert!(
            t0.elapsed() < Duration::from_secs(30),
            "the cyclic phase did not start"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    disturb();
    let o = run.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "run: {stderr}");
    assert!(
        served.child.try_wait().unwrap().is_none(),
        "serve exited in the disturbance"
    );
    let j: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&summary).unwrap()).unwrap();
    assert_eq!(j["stopped"], "duration");
    // Locked at the end.
    let tail = csv_column(&csv, "max_abs_092c_ns");
    let worst = tail[tail.len().saturating_sub(500)..]
        .iter()
        .copied()
        .fold(0.0f64, f64::max);
    assert!(worst < 1_000.0, "|0x092C| {worst} ns at the end");
    served.kill();
    j
}

#[test]
fn serve_and_run_survive_their_interfaces_going_down_for_50_ms() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let Some(pair) = NetPair::new("d") else {
        return;
    };
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
fn run_survives_a_send_queue_that_stays_full() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let Some(pair) = NetPair::new("q") else {
        return;
    };
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
fn a_segment_that_dies_mid_run_is_reported_and_what_was_measured_is_kept() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let Some(pair) = NetPair::new("k") else {
        return;
    };
    let mut served = pair.serve(&[]);
    let dir = tmp("kill");
    let csv = dir.join("cycles.csv");
    let summary = dir.join("summary.json");
    let run = pair
        .command(
            &pair.ns_b,
            &[
                "run",
                "--iface",
                &pair.if_b,
                "--duration",
                "30",
                // Without it the run keeps trying (and recovers a segment that comes back).
                "--give-up-after",
                "100",
                "--csv",
                csv.to_str().unwrap(),
                "--summary",
                summary.to_str().unwrap(),
            ],
        )
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Kill the segment once the cyclic phase has run a second.
    let t0 = Instant::now();
    while lines(&csv) < 1_000 {
        assert!(
            t0.elapsed() < Duration::from_secs(30),
            "the cyclic phase did not start"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
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
fn a_missing_interface_or_no_raw_socket_permission_is_one_clear_line() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
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
    let Some(pair) = NetPair::new("p") else {
        return;
    };
    // Root without CAP_NET_RAW (dropped from the bounding set).
    let probe = Command::new("setpriv").arg("--version").output();
    if probe.is_err() {
        println!("SKIPPED the capability half: setpriv is not installed");
        return;
    }
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

mod ethercrab_raw {
    //! ethercrab 0.7 with its own Linux raw-socket TX/RX task, in namespace B, against
    //! `ecsync serve` in namespace A.

    use super::*;
    use ecsync_ethercrab::{DcLoop, MedianSync};
    use ecsync_wire::sii::{self, category};
    use ethercrab::std::{ethercat_now, tx_rx_task};
    use ethercrab::subdevice_group::DcConfiguration;
    use ethercrab::{DcSync, MainDevice, MainDeviceConfig, PduStorage, Timeouts, error::Error};

    const MAX_SUBDEVICES: usize = 8;
    const MAX_PDU_DATA: usize = PduStorage::element_size(1100);
    const MAX_FRAMES: usize = 16;
    const PDI_LEN: usize = 256;
    type Storage = PduStorage<MAX_FRAMES, MAX_PDU_DATA>;
    // ethercrab's storage splits once per process: one for each served segment.
    static STORAGE_MII: Storage = PduStorage::new();
    static STORAGE_EBUS: Storage = PduStorage::new();
    const CYCLE: Duration = Duration::from_millis(1);

    /// The string the SII's general category names at `field` (ethercrab's `name()` is the
    /// order string).
    fn sii_string(image: &[u8], field: usize) -> String {
        let general = sii::find_category(image, category::GENERAL).expect("general category");
        let strings = sii::find_category(image, category::STRINGS).expect("strings category");
        let s = sii::string(strings.data, general.data[field]).expect("string");
        String::from_utf8(s.to_vec()).unwrap()
    }

    /// The paper-2024 drives with EBUS ports (10 ns receive stamps) instead of MII.
    fn paper_2024_ebus() -> String {
        let text =
            preset::PAPER_2024_TOML.replace("model = \"servo-mii\"", "model = \"ebus-terminal\"");
        assert!(text.contains("ebus-terminal"));
        text
    }

    /// The paper-2024 preset as it is. Its drives stamp receive times on MII ports every 40 ns
    /// and ethercrab measures each delay from one latch, so its delays can be off by up to
    /// 40 ns whatever the master does (ecsync's own master averages 64 latches: within 20 ns,
    /// see the tests above); the bound here is that grid.
    #[test]
    fn ethercrab_on_its_raw_socket_against_serve_mii_drives() {
        ethercrab_against_serve("c", &STORAGE_MII, None, 40.0);
    }

    /// The same drives with EBUS ports (10 ns stamps): ethercrab's single latch within 20 ns.
    #[test]
    fn ethercrab_on_its_raw_socket_against_serve_ebus_drives() {
        ethercrab_against_serve("e", &STORAGE_EBUS, Some(paper_2024_ebus()), 20.0);
    }

    /// ethercrab's raw socket against `ecsync serve` of the paper-2024 drives (or `config`):
    /// scan, SII identity, SDOs over CoE in PRE-OP, its DC configuration with delays within
    /// `bound_ns` of the truth, SYNC0, OP (the process data as it read the mapping over CoE),
    /// 1000 cycles of `tx_rx_dc`, then the adapter's median loop for 1000 cycles.
    fn ethercrab_against_serve(
        tag: &str,
        storage: &'static Storage,
        config: Option<String>,
        bound_ns: f64,
    ) {
        let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
        let Some(pair) = NetPair::new(tag) else {
            return;
        };
        let text = config.unwrap_or_else(|| preset::PAPER_2024_TOML.to_string());
        let dir = tmp(&format!("ethercrab-{tag}"));
        let path = dir.join("segment.toml");
        std::fs::write(&path, &text).unwrap();
        let _served = pair.serve(&["--config", path.to_str().unwrap()]);
        let specs = ecsync_sim::config::parse_segment("segment.toml", &text).unwrap();
        let seg = Segment::new(&specs).unwrap();
        let n = seg.len();
        let truth: Vec<f64> = seg
            .true_delays_ns(0)
            .into_iter()
            .map(|d| d.expect("every drive has a delay"))
            .collect();
        let expected: Vec<_> = (0..n)
            .map(|i| {
                let e = seg.esc(i);
                (
                    e.device().clone(),
                    sii_string(e.sii_image(), sii::general::ORDER_IDX),
                )
            })
            .collect();

        let (tx, rx, pdu_loop) = storage.try_split().expect("split once");
        let stop = std::sync::Arc::new(AtomicBool::new(false));
        let (ns_b, if_b) = (pair.ns_b.clone(), pair.if_b.clone());
        let stop_io = stop.clone();
        let (ready_tx, ready_rx) = std::sync::mpsc::channel();
        let io = std::thread::spawn(move || {
            ecsync_net::sys::enter_netns(&ns_b).expect("enter namespace B");
            let task = tx_rx_task(&if_b, tx, rx).expect("ethercrab's raw socket");
            let _ = ready_tx.send(());
            let stopped = async {
                while !stop_io.load(Ordering::Relaxed) {
                    async_io::Timer::after(Duration::from_millis(10)).await;
                }
            };
            async_io::block_on(futures_lite::future::or(
                async {
                    let _ = task.await;
                },
                stopped,
            ));
        });
        // The first PDU's timeout runs from its send: wait until the socket is open.
        ready_rx
            .recv_timeout(Duration::from_secs(10))
            .expect("ethercrab's TX/RX task started");
        // ethercrab's defaults (30 ms per PDU, 10 ms per EEPROM wait) are for a master with a
        // core of its own. Here both ends are ordinary processes on a shared VM whose stalls
        // reach tens of ms; a late reply is no error of the segment, a lost one still is (no
        // retries).
        let timeouts = Timeouts {
            pdu: Duration::from_millis(500),
            eeprom: Duration::from_millis(500),
            ..Timeouts::default()
        };
        let maindevice = MainDevice::new(pdu_loop, timeouts, MainDeviceConfig::default());

        let result: Result<(), Error> = futures_lite::future::block_on(async {
            let group = maindevice
                .init_single_group::<MAX_SUBDEVICES, PDI_LEN>(ethercat_now)
                .await?;
            assert_eq!(group.len(), n, "ethercrab found every drive");
            // SII identity.
            for (i, sd) in group.iter(&maindevice).enumerate() {
                let (dev, order) = &expected[i];
                let id = sd.identity();
                assert_eq!(
                    (id.vendor_id, id.product_id, id.revision, id.serial),
                    (dev.vendor_id, dev.product_code, dev.revision, dev.serial),
                    "drive {i}: SII identity"
                );
                assert_eq!(sd.name(), order.as_str(), "drive {i}: order string");
            }
            // Over CoE in PRE-OP, through the drives' mailboxes across the veth pair: the sync
            // mode to DC SYNC0 and read back, the identity and the PDO assignment.
            for (i, sd) in group.iter(&maindevice).enumerate() {
                let (dev, _) = &expected[i];
                sd.sdo_write(0x1c32, 1, 2u16).await?;
                let mode: u16 = sd.sdo_read(0x1c32, 1).await?;
                let product: u32 = sd.sdo_read(0x1018, 2).await?;
                let serial: u32 = sd.sdo_read(0x1018, 4).await?;
                let rx: u16 = sd.sdo_read(0x1c12, 1).await?;
                let tx: u16 = sd.sdo_read(0x1c13, 1).await?;
                assert_eq!(
                    (mode, product, serial, rx, tx),
                    (2, dev.product_code, dev.serial, 0x1600, 0x1a00),
                    "drive {i} over CoE"
                );
            }
            // Its DC configuration: delays against the preset's.
            println!("drive  ethercrab  preset [ns]  error");
            for (i, sd) in group.iter(&maindevice).enumerate() {
                let d = f64::from(sd.propagation_delay());
                println!("{i:>5}  {d:>9}  {:>11.1}  {:>+5.1}", truth[i], d - truth[i]);
                assert!(
                    (d - truth[i]).abs() <= bound_ns,
                    "drive {i}: ethercrab's delay {d} ns, segment's truth {:.1} ns",
                    truth[i]
                );
            }
            // SYNC0, OP, 1000 cycles of tx_rx_dc with ethercrab's own wait.
            let mut group = group;
            for mut sd in group.iter_mut(&maindevice) {
                sd.set_dc_sync(DcSync::Sync0);
            }
            let group = group.into_pre_op_pdi(&maindevice).await?;
            for _ in 0..2_000 {
                group.tx_rx_sync_system_time(&maindevice).await?;
            }
            let group = group
                .configure_dc_sync(
                    &maindevice,
                    DcConfiguration {
                        start_delay: Duration::from_millis(100),
                        sync0_period: CYCLE,
                        sync0_shift: CYCLE / 2,
                    },
                )
                .await?;
            let group = group.into_safe_op(&maindevice).await?;
            let group = group.request_into_op(&maindevice).await?;
            let mut all_op = false;
            // The outputs as the CoE mapping lays them (controlword, mode, padding, target
            // position): each drive enabled through CiA 402 and sent to 1000 x (i + 1).
            for k in 0..1_000u32 {
                let cw: u16 = match k {
                    0..300 => 0x0006,
                    300..400 => 0x0007,
                    _ => 0x000f,
                };
                for (i, sd) in group.iter(&maindevice).enumerate() {
                    let mut o = sd.outputs_raw_mut();
                    o[..2].copy_from_slice(&cw.to_le_bytes());
                    o[2] = 8;
                    o[4..8].copy_from_slice(&(1_000 * (i as i32 + 1)).to_le_bytes());
                }
                let now = Instant::now();
                let r = group.tx_rx_dc(&maindevice).await?;
                all_op |= r.all_op();
                async_io::Timer::at(now + r.extra.next_cycle_wait).await;
            }
            assert!(all_op, "every drive reached OP");
            for (i, sd) in group.iter(&maindevice).enumerate() {
                let inp = sd.inputs_raw();
                let status = u16::from_le_bytes([inp[0], inp[1]]);
                let position = i32::from_le_bytes(inp[4..8].try_into().unwrap());
                assert_eq!(
                    (status, inp[2], position),
                    (0x1237, 8, 1_000 * (i as i32 + 1)),
                    "drive {i}: statusword, mode display, position actual"
                );
            }
            // 0x092C: every drive in sync with the reference.
            for (i, sd) in group.iter(&maindevice).enumerate() {
                let raw = sd.register_read::<u32>(0x092cu16).await?;
                let mag = raw & 0x7fff_ffff;
                assert!(mag < 100, "drive {i}: |0x092C| = {mag} ns");
            }
            // The adapter: ecsync's median controller decides the waits, 1000 cycles.
            let mut dc = DcLoop::new(MedianSync::new(11, 0.01, 200), CYCLE).unwrap();
            let mut wkc_ok = 0;
            let mut errors = Vec::new();
            let mut sent = Instant::now();
            for _ in 0..1_001 {
                let r = group.tx_rx_dc(&maindevice).await?;
                wkc_ok += usize::from(r.working_counter == 3 * n as u16);
                let next = dc.update(sent, Instant::now(), &r.extra);
                if dc.cycles() > 200 {
                    errors.push(dc.last().error_ns);
                }
                async_io::Timer::at(next).await;
                sent = Instant::now();
            }
            assert_eq!(dc.cycles(), 1_000, "the adapter ran 1000 cycles");
            assert!(wkc_ok >= 995, "process data exchanged ({wkc_ok} of 1001)");
            errors.sort_unstable();
            let median = errors[errors.len() / 2];
            println!(
                "adapter: median of the controller's phase error after initialisation {median} ns, \
                 correction {} ns",
                dc.last().correction_ns
            );
            // The phase is held: the controller's error is centred (the host's jitter aside).
            assert!(median.abs() < 20_000, "median phase error {median} ns");
            Ok(())
        });
        stop.store(true, Ordering::Relaxed);
        let _ = io.join();
        result.expect("ethercrab over its raw socket against ecsync serve");
    }
}

mod ethercrab_faults {
    //! ethercrab 0.7 against `ecsync serve --faults`: the reference switched off for 200 ms
    //! in OP. What ethercrab does is recorded, not judged (it is not ours to fix): the fault
    //! reaches a real master as a real power cycle would.

    use super::*;
    use ethercrab::std::{ethercat_now, tx_rx_task};
    use ethercrab::subdevice_group::DcConfiguration;
    use ethercrab::{DcSync, MainDevice, MainDeviceConfig, PduStorage, Timeouts, error::Error};

    const MAX_PDU_DATA: usize = PduStorage::element_size(1100);
    type Storage = PduStorage<16, MAX_PDU_DATA>;
    static STORAGE: Storage = PduStorage::new();
    const CYCLE: Duration = Duration::from_millis(1);

    #[test]
    fn ethercrab_meets_a_reference_power_cycle_and_does_not_bring_it_back() {
        let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
        let Some(pair) = NetPair::new("x") else {
            return;
        };
        let dir = tmp("ethercrab-faults");
        let faults = dir.join("faults.toml");
        // From ethercrab's first frame with process data (its PRE-OP system time sync): the
        // reference off at 4 s, when it has been in OP for a while.
        std::fs::write(
            &faults,
            "[[fault]]\nat_s = 4\nfor_s = 0.2\nkind = \"power_cycle\"\nslave = \"reference\"\n",
        )
        .unwrap();
        let _served = pair.serve(&["--faults", faults.to_str().unwrap()]);
        let n = 6u16;
        let (tx, rx, pdu_loop) = STORAGE.try_split().expect("split once");
        let stop = std::sync::Arc::new(AtomicBool::new(false));
        let (ns_b, if_b) = (pair.ns_b.clone(), pair.if_b.clone());
        let stop_io = stop.clone();
        let (ready_tx, ready_rx) = std::sync::mpsc::channel();
        let io = std::thread::spawn(move || {
            ecsync_net::sys::enter_netns(&ns_b).expect("enter namespace B");
            let task = tx_rx_task(&if_b, tx, rx).expect("ethercrab's raw socket");
            let _ = ready_tx.send(());
            let stopped = async {
                while !stop_io.load(Ordering::Relaxed) {
                    async_io::Timer::after(Duration::from_millis(10)).await;
                }
            };
            async_io::block_on(futures_lite::future::or(
                async {
                    let _ = task.await;
                },
                stopped,
            ));
        });
        ready_rx
            .recv_timeout(Duration::from_secs(10))
            .expect("ethercrab's TX/RX task started");
        // Its own PDU timeout (30 ms): the frames of the 200 ms off are lost, not late.
        let timeouts = Timeouts {
            eeprom: Duration::from_millis(500),
            ..Timeouts::default()
        };
        let maindevice = MainDevice::new(pdu_loop, timeouts, MainDeviceConfig::default());
        let result: Result<(), Error> = futures_lite::future::block_on(async {
            let mut group = maindevice.init_single_group::<8, 256>(ethercat_now).await?;
            for mut sd in group.iter_mut(&maindevice) {
                sd.set_dc_sync(DcSync::Sync0);
            }
            let group = group.into_pre_op_pdi(&maindevice).await?;
            for _ in 0..2_000 {
                group.tx_rx_sync_system_time(&maindevice).await?;
            }
            let group = group
                .configure_dc_sync(
                    &maindevice,
                    DcConfiguration {
                        start_delay: Duration::from_millis(100),
                        sync0_period: CYCLE,
                        sync0_shift: CYCLE / 2,
                    },
                )
                .await?;
            let group = group.into_safe_op(&maindevice).await?;
            let group = group.request_into_op(&maindevice).await?;
            // Cycles until well after the power cycle: what each one returned.
            let (mut ok, mut errors, mut short_wkc_after, mut all_op_after) = (0, 0, 0, 0);
            let mut first_error_at = None;
            let t0 = Instant::now();
            while t0.elapsed() < Duration::from_secs(6) {
                let now = Instant::now();
                match group.tx_rx_dc(&maindevice).await {
                    Ok(r) => {
                        ok += 1;
                        if first_error_at.is_some() {
                            short_wkc_after += usize::from(r.working_counter < 3 * n);
                            all_op_after += usize::from(r.all_op());
                        }
                        async_io::Timer::at(now + r.extra.next_cycle_wait.min(CYCLE * 2)).await;
                    }
                    Err(e) => {
                        errors += 1;
                        first_error_at.get_or_insert((t0.elapsed(), format!("{e:?}")));
                    }
                }
            }
            println!(
                "ethercrab: {ok} cycles answered, {errors} failed (the first at {:?}); after it: \
                 {short_wkc_after} cycles with a short working counter, {all_op_after} with every \
                 drive in OP",
                first_error_at
            );
            // What a real power cycle does to ethercrab 0.7, as the segment played it (seen on
            // this machine: 7 cycles failed with Timeout(Pdu), then every cycle short): the
            // cycles of the 200 ms off fail (its PDUs time out); the drives behind the
            // reference, without outputs for those 200 ms, leave OP on their process data
            // watchdogs (SAFE-OP, 0x001B); afterwards the working counter stays short for good
            // and all_op() says so, since ethercrab brings neither the reset slave nor the
            // others back.
            assert!(errors >= 1, "the frames of the 200 ms off failed");
            let (at, what) = first_error_at.clone().unwrap();
            assert!(
                at > Duration::from_millis(2_000),
                "the first failure at {at:?}: {what}"
            );
            assert!(what.contains("Timeout"), "ethercrab's error: {what}");
            assert!(
                short_wkc_after > 500,
                "short working counters after: {short_wkc_after}"
            );
            assert_eq!(
                all_op_after, 0,
                "ethercrab's all_op() after the power cycle: {all_op_after}"
            );
            Ok(())
        });
        stop.store(true, Ordering::Relaxed);
        let _ = io.join();
        result.expect("ethercrab against ecsync serve --faults");
    }
}

mod raw_frames {
    //! Single frames from the crate's own raw socket in namespace B against `ecsync serve` in
    //! namespace A: what a real ESC answers at its port 0, whatever the master's source address,
    //! and a VLAN-tagged request answered in its tag.

    use super::*;
    use ecsync_net::sys::{PacketSocket, TPID_8021AD, TPID_8021Q, VlanTag};
    use ecsync_wire::{Command as Cmd, DatagramAddress, EcatFrame, FrameBuilder};

    /// A locally administered unicast address (bit 0x02 of the first byte set).
    const LOCAL_MAC: [u8; 6] = [0x02, 0x00, 0x00, 0x00, 0x00, 0x01];
    /// A globally unique one.
    const GLOBAL_MAC: [u8; 6] = [0x00, 0x1b, 0x21, 0xec, 0x00, 0x02];

    /// A BRD of 0x0000 (ESC type, 1 byte) from `src` with datagram index `index`, in `tag`.
    fn brd(src: [u8; 6], index: u8, tag: Option<VlanTag>) -> Vec<u8> {
        let mut buf = [0u8; 128];
        let mut b = FrameBuilder::new(&mut buf, [0xff; 6], src).unwrap();
        b.push_zeroed(Cmd::Brd, index, DatagramAddress::position(0, 0x0000), 1)
            .unwrap();
        let n = b.finish();
        let mut f = buf[..n].to_vec();
        if let Some(t) = tag {
            f.splice(12..12, t.to_bytes());
        }
        f
    }

    /// What came back for one request.
    #[derive(Debug)]
    struct Answer {
        /// The frame as received (tags the kernel took off are not in it).
        bytes: Vec<u8>,
        /// The tag the kernel took off.
        stripped: Option<VlanTag>,
    }

    impl Answer {
        /// The tag the answer carried, wherever the kernel left it, and the untagged frame.
        fn untagged(&self) -> (Option<VlanTag>, Vec<u8>) {
            let mut f = self.bytes.clone();
            let et = u16::from_be_bytes([f[12], f[13]]);
            if et == TPID_8021Q || et == TPID_8021AD {
                let t = VlanTag {
                    tpid: et,
                    tci: u16::from_be_bytes([f[14], f[15]]),
                };
                f.drain(12..16);
                assert!(self.stripped.is_none(), "two tags");
                return (Some(t), f);
            }
            (self.stripped, f)
        }
    }

    /// Sends each frame of `requests` from a VLAN-aware raw socket on `iface` in namespace
    /// `ns` and collects every frame that arrives within 300 ms after each.
    fn exchange(ns: &str, iface: &str, requests: Vec<Vec<u8>>) -> Vec<Vec<Answer>> {
        let (ns, iface) = (ns.to_string(), iface.to_string());
        std::thread::spawn(move || {
            ecsync_net::sys::enter_netns(&ns).expect("enter namespace B");
            let sock = PacketSocket::open_vlan_aware(&iface).expect("raw socket");
            let mut buf = [0u8; 2048];
            requests
                .iter()
                .map(|req| {
                    sock.send(req).expect("send");
                    let t0 = Instant::now();
                    let mut got = Vec::new();
                    while t0.elapsed() < Duration::from_millis(300) {
                        match sock.recv(&mut buf).expect("receive") {
                            Some(r) => got.push(Answer {
                                bytes: buf[..r.len].to_vec(),
                                stripped: r.vlan,
                            }),
                            None => {
                                sock.wait(10_000_000).expect("wait");
                            }
                        }
                    }
                    got
                })
                .collect()
        })
        .join()
        .expect("the raw-socket thread")
    }

    /// The answer's only datagram: (index, ADP, working counter, data).
    fn datagram(frame: &[u8]) -> (u8, u16, u16, Vec<u8>) {
        let f = EcatFrame::new_checked(frame).expect("an EtherCAT frame");
        let d = f.datagrams().next().unwrap().unwrap();
        (d.index(), d.adp(), d.wkc(), d.data().to_vec())
    }

    /// The paper-2024 segment: six ET1100-class drives.
    const SLAVES: u16 = 6;

    #[test]
    fn a_master_with_a_locally_administered_address_is_answered() {
        let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
        let Some(pair) = NetPair::new("l") else {
            return;
        };
        // The master's NIC has a locally administered address, and the master sends from it.
        ip(&[
            "-n",
            &pair.ns_b,
            "link",
            "set",
            "dev",
            &pair.if_b,
            "address",
            "02:00:00:00:00:01",
        ])
        .expect("set the MAC address");
        let _served = pair.serve(&[]);
        let answers = exchange(
            &pair.ns_b,
            &pair.if_b,
            vec![brd(LOCAL_MAC, 0x31, None), brd(GLOBAL_MAC, 0x32, None)],
        );
        for (a, (index, src)) in answers.iter().zip([(0x31, LOCAL_MAC), (0x32, GLOBAL_MAC)]) {
            // Exactly one answer: the segment processed the request once and did not take its
            // own answer, which its socket sees leave, for a new request.
            assert_eq!(a.len(), 1, "request {index:#x} from {src:02x?}: {a:02x?}");
            let (tag, f) = a[0].untagged();
            assert_eq!(tag, None);
            // The first ESC marks the source address (bit 0x02 of the first byte).
            assert_eq!(f[6], src[0] | 0x02);
            assert_eq!(&f[7..12], &src[1..]);
            // Every drive read: working counter 6, ADP incremented by each, ET1100 type 0x11.
            assert_eq!(datagram(&f), (index, SLAVES, SLAVES, vec![0x11]));
        }
    }

    #[test]
    fn a_vlan_tagged_request_is_answered_in_its_tag() {
        let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
        let Some(pair) = NetPair::new("v") else {
            return;
        };
        let _served = pair.serve(&[]);
        // 802.1Q VID 0x123 PCP 5, 802.1ad VID 7 PCP 1, PCP 6 on VID 0 (priority tag), untagged.
        let tags = [
            Some(VlanTag {
                tpid: TPID_8021Q,
                tci: 0xa123,
            }),
            Some(VlanTag {
                tpid: TPID_8021AD,
                tci: 0x2007,
            }),
            Some(VlanTag {
                tpid: TPID_8021Q,
                tci: 0xc000,
            }),
            None,
        ];
        // Wireshark on the master's side, started before the first request.
        let pcap = tmp("vlan").join("master-side.pcapng");
        let mut shark = tshark_capture(&pair, &pcap);
        let requests: Vec<Vec<u8>> = tags
            .iter()
            .enumerate()
            .map(|(i, t)| brd(GLOBAL_MAC, 0x40 + i as u8, *t))
            .collect();
        let answers = exchange(&pair.ns_b, &pair.if_b, requests);
        for (i, (a, t)) in answers.iter().zip(tags).enumerate() {
            assert_eq!(a.len(), 1, "request {i}: {a:02x?}");
            let (tag, f) = a[0].untagged();
            assert_eq!(tag, t, "request {i}: the answer's tag");
            assert_eq!(f[6], GLOBAL_MAC[0] | 0x02, "request {i} passed the segment");
            assert_eq!(datagram(&f), (0x40 + i as u8, SLAVES, SLAVES, vec![0x11]));
        }
        // The same seen by Wireshark's dissectors on the wire: each answer (source address
        // marked) in the VLAN of its request, with the same VID and PCP, EtherCAT inside.
        let Some(child) = shark.as_mut() else { return };
        std::thread::sleep(Duration::from_millis(500));
        let _ = Command::new("kill")
            .args(["-INT", &child.id().to_string()])
            .status();
        let _ = child.wait();
        let o = Command::new("tshark")
            .arg("-r")
            .arg(&pcap)
            .args([
                "-Y",
                "ecat",
                "-T",
                "fields",
                "-e",
                "eth.src",
                "-e",
                "eth.type",
                "-e",
                "vlan.id",
                "-e",
                "vlan.priority",
                "-e",
                "ieee8021ad.id",
                "-e",
                "ieee8021ad.priority",
                "-e",
                "ecat.idx",
                "-e",
                "ecat.cnt",
            ])
            .output()
            .expect("tshark -r");
        let out = String::from_utf8_lossy(&o.stdout);
        println!("{out}");
        let answers: Vec<&str> = out.lines().filter(|l| l.starts_with("02:")).collect();
        assert_eq!(
            answers,
            [
                // source, outer EtherType, 802.1Q VID and PCP, 802.1ad VID and PCP, index, wkc
                "02:1b:21:ec:00:02\t0x8100\t291\t5\t\t\t0x40\t6",
                "02:1b:21:ec:00:02\t0x88a8\t\t\t7\t1\t0x41\t6",
                "02:1b:21:ec:00:02\t0x8100\t0\t6\t\t\t0x42\t6",
                "02:1b:21:ec:00:02\t0x88a4\t\t\t\t\t0x43\t6",
            ],
            "{out}"
        );
    }

    /// tshark capturing on the master's interface into `pcap`, once it is capturing; `None`
    /// (after saying so) where tshark is not installed outside CI.
    fn tshark_capture(pair: &NetPair, pcap: &Path) -> Option<Child> {
        if Command::new("tshark").arg("--version").output().is_err() {
            assert!(
                std::env::var_os("CI").is_none(),
                "tshark is missing in CI: .ci/run must install it"
            );
            println!("SKIPPED the Wireshark half: tshark is not installed");
            return None;
        }
        let mut child = Command::new("ip")
            .args([
                "netns", "exec", &pair.ns_b, "tshark", "-i", &pair.if_b, "-w",
            ])
            .arg(pcap)
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .expect("spawn tshark");
        let stderr = child.stderr.take().unwrap();
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            for l in BufReader::new(stderr).lines().map_while(Result::ok) {
                let _ = tx.send(l);
            }
        });
        let t0 = Instant::now();
        loop {
            match rx.recv_timeout(Duration::from_secs(10)) {
                Ok(l) if l.contains("Capturing on") => break,
                Ok(_) => {}
                Err(e) => panic!("tshark did not start capturing: {e}"),
            }
            assert!(t0.elapsed() < Duration::from_secs(10));
        }
        // dumpcap says so a moment before its first packet is taken.
        std::thread::sleep(Duration::from_secs(1));
        Some(child)
    }
}

mod host_stall {
    //! Issue 11, acceptance 2 (the veth half; the simulator's is in ecsync-master's tests): the
    //! same cyclic driver over the real raw socket meets a host stall of two and a half periods
    //! the same way: it skips the two slots that passed and sends one frame, no burst.

    use super::*;
    use ecsync_dc::MedianSync;
    use ecsync_master::cyclic::{CyclicConfig, CyclicEngine};
    use ecsync_master::driver::{
        CyclicDriver, CyclicLimits, ExchangeStats, ProcedureConfig, run_procedure,
    };
    use ecsync_master::transport::{HostStall, Transport};
    use ecsync_master::{BringupConfig, Engine, Stage, bringup};

    #[test]
    fn a_stall_of_two_and_a_half_periods_skips_two_cycles_over_the_veth_pair() {
        let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
        let Some(pair) = NetPair::new("s") else {
            return;
        };
        let _served = pair.serve(&[]);
        let (ns, iface) = (pair.ns_b.clone(), pair.if_b.clone());
        let period = 1_000_000u64;
        let seen = std::thread::spawn(move || {
            ecsync_net::sys::enter_netns(&ns).expect("enter namespace B");
            let mut link = ecsync_net::RealLink::open(&iface).expect("raw socket");
            let cfg = BringupConfig {
                until: Stage::Op,
                static_drift_frames: 1_000,
                lock_hold_checks: 50,
                ..BringupConfig::default()
            };
            let mut engine = Engine::new(move |l| bringup(l, cfg));
            let net = run_procedure(
                &mut link,
                &mut engine,
                ProcedureConfig::default(),
                &mut ExchangeStats::default(),
                |_, _, _| {},
            )
            .expect("the link")
            .expect("the bring-up");
            let cyc = CyclicConfig {
                period_ns: period as u32,
                reference_station: net.slaves[usize::from(net.reference)].station,
                pdi_len: net.pdi_len,
                measure_init_frames: 2,
                reference_offset_ns: 0,
                lrw: net.lrw.clone(),
            };
            let first = (link.now().as_ns() / period + 2) * period;
            let mut eng = CyclicEngine::new(
                MedianSync::new(11, 0.01, 2),
                cyc,
                ecsync_dc::time::MasterInstant::from_ns(first),
            )
            .unwrap();
            let mut tr = HostStall::new(
                link,
                5,
                ecsync_dc::time::MasterDuration::from_ns(period * 5 / 2),
            );
            let mut driver = CyclicDriver::new(CyclicLimits {
                max_cycles: Some(12),
                ..CyclicLimits::default()
            });
            let mut seen = Vec::new();
            driver
                .run(&mut tr, &mut eng, u64::MAX, None, |_, c| {
                    seen.push((c.record.cycle, c.skipped_before, c.record.send.as_ns()));
                })
                .expect("the cyclic phase");
            seen
        })
        .join()
        .expect("the master thread");
        println!("cycles, skipped before, send times: {seen:?}");
        assert_eq!(seen.len(), 12);
        // Cycles 0-4 ran; the stalled one woke two and a half periods late (a few tens of
        // microseconds more on this host) and skipped the two slots that passed.
        let k = seen
            .iter()
            .position(|s| s.0 >= 5)
            .expect("a cycle after the stall");
        assert_eq!(seen[k].1, 2, "{seen:?}");
        assert_eq!(seen[k].0, 7, "{seen:?}");
        // One frame for the three slots, then on schedule: no burst.
        assert!(seen[k + 1].2 - seen[k].2 > period * 2 / 5, "{seen:?}");
        assert_eq!(seen[k + 1].0, 8, "{seen:?}");
    }
}

/// SOEM (pysoem from PyPI) against `ecsync serve` over the veth pair.
mod soem {
    use super::*;

    /// A Python that has pysoem: `ECSYNC_PYSOEM_PYTHON`, else the `python3` on the path. `None`
    /// (after saying so) when there is none; in CI that is an error, not a skip.
    pub(super) fn python() -> Option<String> {
        let py = std::env::var("ECSYNC_PYSOEM_PYTHON").unwrap_or_else(|_| "python3".into());
        let ok = Command::new(&py)
            .args(["-c", "import pysoem"])
            .output()
            .is_ok_and(|o| o.status.success());
        if ok {
            return Some(py);
        }
        assert!(
            std::env::var("CI").is_err(),
            "pysoem is not installed for {py} (.ci/run installs it into a venv and sets ECSYNC_PYSOEM_PYTHON)"
        );
        println!("SKIPPED: no pysoem for {py} (pip install pysoem, or set ECSYNC_PYSOEM_PYTHON)");
        None
    }

    #[test]
    fn soem_scans_the_drives_over_coe_lists_their_dictionary_and_runs_them_in_op() {
        // SOEM waits for its frames spinning on a core: not beside a timed run on this
        // two-core machine.
        let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
        let Some(py) = python() else { return };
        let Some(pair) = NetPair::new("so") else {
            return;
        };
        let _serve = pair.serve(&[]);
        let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/pysoem/scan.py");
        let o = Command::new("ip")
            .args(["netns", "exec", &pair.ns_b, &py])
            .arg(&script)
            .arg(&pair.if_b)
            .output()
            .expect("run pysoem");
        assert!(
            o.status.success(),
            "pysoem: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("JSON");
        println!("{v}");
        assert_eq!(v["slaves"], 6, "SOEM found the six drives");
        let dev = ecsync_sim::model::DeviceInfo::servo_drive(0);
        for (i, d) in v["drives"].as_array().unwrap().iter().enumerate() {
            assert_eq!(d["name"], dev.name.as_str(), "drive {i}: SII name");
            assert_eq!(d["man"], dev.vendor_id, "drive {i}: vendor from the SII");
            assert_eq!(
                d["vendor_sdo"], dev.vendor_id,
                "drive {i}: 0x1018:01 over CoE"
            );
            assert_eq!(d["product_sdo"], dev.product_code, "drive {i}: 0x1018:02");
            assert_eq!(
                (d["rx_assign"].as_u64(), d["tx_assign"].as_u64()),
                (Some(0x1600), Some(0x1a00)),
                "drive {i}: PDO assignment"
            );
            assert_eq!(d["rx_map_count"], dev.outputs.len(), "drive {i}: 0x1600:00");
            // SDO Information: the dictionary, an object's name and its entries' names.
            let od: Vec<u64> = d["od"]
                .as_array()
                .unwrap()
                .iter()
                .filter_map(|x| x.as_u64())
                .collect();
            for want in [
                0x1000, 0x1018, 0x1c12, 0x1c13, 0x1c32, 0x1c33, 0x6040, 0x6064,
            ] {
                assert!(od.contains(&want), "drive {i}: {want:#06x} listed: {od:x?}");
            }
            assert_eq!(d["identity_name"], "Identity");
            assert_eq!(
                d["identity_entries"],
                serde_json::json!([
                    "Subindex 000",
                    "Vendor ID",
                    "Product code",
                    "Revision",
                    "Serial number"
                ])
            );
        }
        // The mapping SOEM built from the CoE PDO assignment and mapping: 16 + 18 bytes for
        // the drives left as they are, 8 + 8 for every other one, which the script's config
        // function mapped anew in PRE-OP (from the SII SOEM would have 34 for every drive).
        let short: Vec<bool> = v["short"]
            .as_array()
            .unwrap()
            .iter()
            .map(|b| b.as_bool().unwrap())
            .collect();
        assert_eq!(short, [false, true, false, true, false, true]);
        for (k, m) in v["mapped"].as_array().unwrap().iter().enumerate() {
            let want = if short[k] { [8, 8] } else { [16, 18] };
            assert_eq!(m, &serde_json::json!(want), "drive {k}: outputs, inputs");
        }
        assert_eq!(v["io_map"], 3 * 34 + 3 * 16);
        assert_eq!(v["op"], true, "every drive in OP");
        assert_eq!(v["wkc"], v["expected_wkc"]);
        // Enabled through the CiA 402 state machine: operation enabled, following the
        // target (statusword 0x1237), in cyclic synchronous position (8), at the target.
        for (k, e) in v["drive_inputs"].as_array().unwrap().iter().enumerate() {
            assert_eq!(
                e,
                &serde_json::json!([0x1237, 8, 1000 * (k + 1)]),
                "drive {k}: statusword, mode, position actual"
            );
        }
        assert_eq!(v["sm_event_missed"], serde_json::json!([0, 0, 0, 0, 0, 0]));
    }
}

mod esi_drives {
    //! Issue 13, acceptance 5, over the veth pair: `ecsync serve` of two Ingenia EVS-NET-01
    //! servo drives built from the vendor's ESI (../shared/esi/) and the project's own drive
    //! from its shipped ESI; ethercrab on its raw socket and SOEM through pysoem scan them and
    //! read their identity and PDO assignment over CoE. Independent truth: the ESI's values
    //! (vendor 0x029C, product 61935618 for the Ingenia drive, RPDO 1 / TPDO 1 assigned by
    //! default, its RPDO 1 entries: controlword, position and velocity set-points, mode).

    use super::*;
    use ethercrab::std::{ethercat_now, tx_rx_task};
    use ethercrab::{MainDevice, MainDeviceConfig, PduStorage, Timeouts, error::Error};

    type Storage = PduStorage<16, { PduStorage::element_size(1100) }>;
    static STORAGE: Storage = PduStorage::new();

    /// The ESI folder (as the ESC's tests find it), `None` outside CI when it is missing.
    fn esi_dir() -> Option<PathBuf> {
        let candidates = std::env::var_os("ECSYNC_SHARED")
            .map(|d| PathBuf::from(d).join("esi"))
            .into_iter()
            .chain([
                PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/esi"),
                PathBuf::from("/work/shared/esi"),
            ]);
        for d in candidates {
            if d.join("ingenia-evs-net-01.xml").is_file() {
                return Some(d);
            }
        }
        assert!(
            std::env::var_os("CI").is_none(),
            "the ESI files are missing in CI"
        );
        println!("SKIPPED: no ../shared/esi");
        None
    }

    /// The network file: two Ingenia drives, then the shipped virtual drive.
    fn network(dir: &Path) -> (PathBuf, String) {
        let ingenia = dir.join("ingenia-evs-net-01.xml");
        let shipped =
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../../esi/ecsync-virtual-drive.xml");
        let text = format!(
            "[segment]\n\
             [[segment.slave]]\nname = \"a\"\nupstream = \"master\"\nesi = \"{i}\"\nserial = 11\n\n\
             [[segment.slave]]\nname = \"b\"\nupstream = \"a\"\nesi = \"{i}\"\nserial = 12\n\n\
             [[segment.slave]]\nname = \"c\"\nupstream = \"b\"\nesi = \"{s}\"\n",
            i = ingenia.display(),
            s = shipped.display()
        );
        let d = tmp("esi-net");
        let path = d.join("esi.toml");
        std::fs::write(&path, &text).unwrap();
        (path, text)
    }

    // The ESI's `<Vendor><Id>#x0000029c` and `<Type ProductCode="61935618">`.
    const INGENIA: (u32, u32) = (0x0000_029c, 61_935_618);

    #[test]
    fn ethercrab_and_soem_scan_drives_built_from_esi_files_over_the_veth_pair() {
        let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
        let Some(dir) = esi_dir() else { return };
        let Some(pair) = NetPair::new("i") else {
            return;
        };
        let (path, text) = network(&dir);
        let specs = ecsync_sim::config::parse_segment(path.to_str().unwrap(), &text).unwrap();
        let seg = Segment::new(&specs).unwrap();
        let devices: Vec<_> = (0..seg.len())
            .map(|i| seg.esc(i).device().clone())
            .collect();
        assert_eq!((devices[0].vendor_id, devices[0].product_code), INGENIA);
        let _served = pair.serve(&["--config", path.to_str().unwrap()]);

        // ethercrab on its raw socket: the scan, then CoE in PRE-OP.
        let (tx, rx, pdu_loop) = STORAGE.try_split().expect("split once");
        let stop = std::sync::Arc::new(AtomicBool::new(false));
        let (ns_b, if_b) = (pair.ns_b.clone(), pair.if_b.clone());
        let stop_io = stop.clone();
        let (ready_tx, ready_rx) = std::sync::mpsc::channel();
        let io = std::thread::spawn(move || {
            ecsync_net::sys::enter_netns(&ns_b).expect("enter namespace B");
            let task = tx_rx_task(&if_b, tx, rx).expect("ethercrab's raw socket");
            let _ = ready_tx.send(());
            let stopped = async {
                while !stop_io.load(Ordering::Relaxed) {
                    async_io::Timer::after(Duration::from_millis(10)).await;
                }
            };
            async_io::block_on(futures_lite::future::or(
                async {
                    let _ = task.await;
                },
                stopped,
            ));
        });
        ready_rx
            .recv_timeout(Duration::from_secs(10))
            .expect("ethercrab's TX/RX task started");
        let timeouts = Timeouts {
            pdu: Duration::from_millis(500),
            eeprom: Duration::from_millis(500),
            ..Timeouts::default()
        };
        let maindevice = MainDevice::new(pdu_loop, timeouts, MainDeviceConfig::default());
        let result: Result<(), Error> = futures_lite::future::block_on(async {
            let group = maindevice.init_single_group::<8, 256>(ethercat_now).await?;
            assert_eq!(group.len(), devices.len());
            for (i, sd) in group.iter(&maindevice).enumerate() {
                let d = &devices[i];
                let id = sd.identity();
                assert_eq!(
                    (id.vendor_id, id.product_id, id.revision, id.serial),
                    (d.vendor_id, d.product_code, d.revision, d.serial),
                    "slave {i}: SII identity"
                );
                let vendor: u32 = sd.sdo_read(0x1018, 1).await?;
                let product: u32 = sd.sdo_read(0x1018, 2).await?;
                let rx: u16 = sd.sdo_read(0x1c12, 1).await?;
                let tx: u16 = sd.sdo_read(0x1c13, 1).await?;
                let first: u32 = sd.sdo_read(0x1600, 1).await?;
                assert_eq!(
                    (vendor, product, rx, tx, first),
                    (d.vendor_id, d.product_code, 0x1600, 0x1a00, 0x6040_0010),
                    "slave {i} over CoE"
                );
            }
            Ok(())
        });
        stop.store(true, Ordering::Relaxed);
        let _ = io.join();
        result.expect("ethercrab against the ESI drives");

        // SOEM through pysoem.
        let Some(py) = super::soem::python() else {
            return;
        };
        let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/pysoem/scan_esi.py");
        let o = Command::new("ip")
            .args(["netns", "exec", &pair.ns_b, &py])
            .arg(&script)
            .arg(&pair.if_b)
            .output()
            .expect("run pysoem");
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        println!("{v}");
        assert_eq!(v["slaves"], 3);
        for (i, d) in v["drives"].as_array().unwrap().iter().enumerate() {
            let dev = &devices[i];
            assert_eq!(
                (d["man"].as_u64(), d["id"].as_u64(), d["rev"].as_u64()),
                (
                    Some(u64::from(dev.vendor_id)),
                    Some(u64::from(dev.product_code)),
                    Some(u64::from(dev.revision))
                ),
                "slave {i}: SII identity"
            );
            assert_eq!(d["vendor_sdo"], dev.vendor_id, "slave {i}: 0x1018:01");
            assert_eq!(d["product_sdo"], dev.product_code, "slave {i}: 0x1018:02");
            assert_eq!(
                (d["rx_assign"].as_u64(), d["tx_assign"].as_u64()),
                (Some(0x1600), Some(0x1a00))
            );
        }
        // The Ingenia drive's RPDO 1 as its ESI writes it.
        assert_eq!(
            v["drives"][0]["rx_map"],
            serde_json::json!([
                0x6040_0010u32,
                0x607a_0020u32,
                0x60ff_0020u32,
                0x6060_0008u32
            ])
        );
        // Two Ingenia drives (11 + 11 bytes each) and the virtual drive (16 + 18).
        assert_eq!(v["io_map"], 2 * 22 + 34);
    }
}

/// The preset's crystals against the reference's (position 0), ppm: the truth a twin's are
/// checked against (the segment runs on this host's clock, so only relative figures compare).
fn true_relative_ppm() -> Vec<f64> {
    let specs = ecsync_sim::config::parse_segment("paper-2024", preset::PAPER_2024_TOML).unwrap();
    let r = specs[0].crystal.ppm;
    specs
        .iter()
        .map(|s| ((1.0 + s.crystal.ppm * 1e-6) / (1.0 + r * 1e-6) - 1.0) * 1e6)
        .collect()
}

/// `compare` on a twin's segment with the preset's host, run and method tables ranks the
/// methods as `compare` on the preset does.
fn ranks_as_the_preset(twin_text: &str, dir: &Path) {
    let rest = preset::PAPER_2024_TOML
        .find("\n[host]")
        .map(|at| &preset::PAPER_2024_TOML[at..])
        .expect("the preset has a [host] table");
    let scenario = dir.join("twin-scenario.toml");
    std::fs::write(&scenario, format!("{twin_text}\n{rest}")).unwrap();
    let preset_file = dir.join("paper-2024.toml");
    std::fs::write(&preset_file, preset::PAPER_2024_TOML).unwrap();
    let on_twin = ranking(&scenario, &dir.join("cmp-twin"));
    let on_preset = ranking(&preset_file, &dir.join("cmp-preset"));
    println!("ranking on the twin: {on_twin:?}; on the preset: {on_preset:?}");
    assert_eq!(on_twin, on_preset, "the twin ranks the methods otherwise");
}

/// `compare` on a scenario file, short (one run, 20 000 cycles), its ranking.
fn ranking(scenario: &Path, out: &Path) -> Vec<String> {
    let o = Command::new(ecsync())
        .args([
            "compare",
            "--config",
            scenario.to_str().unwrap(),
            "--runs",
            "1",
            "--cycles",
            "20000",
            "--warmup-s",
            "15",
            "--seed",
            "7",
            "--host",
            "preempt-rt-stress",
            "--threads",
            "2",
            "--quiet",
            "--json",
            "--out",
            out.to_str().unwrap(),
        ])
        .output()
        .expect("run ecsync compare");
    assert!(
        o.status.success(),
        "compare --config {}: {}",
        scenario.display(),
        String::from_utf8_lossy(&o.stderr)
    );
    let j: serde_json::Value = serde_json::from_slice(&o.stdout).expect("compare JSON");
    j["recommendation"]["ranking"]
        .as_array()
        .expect("a ranking")
        .iter()
        .map(|m| m.as_str().unwrap_or_default().to_string())
        .collect()
}

/// Issue 14's first acceptance: `run --scan-only --save-network` against `serve --preset
/// paper-2024` writes a twin on which `bringup` finds every delay within 20 ns and every crystal
/// against the reference within 0.1 ppm of the preset's truth, and `compare` ranks the methods
/// as on the preset (same host, seed, run and method tables).
#[test]
fn a_twin_saved_over_veth_has_the_preset_s_delays_crystals_and_ranking() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let Some(pair) = NetPair::new("tw") else {
        return;
    };
    let dir = tmp("twin");
    let twin = dir.join("twin.toml");
    {
        let _served = pair.serve(&[]);
        let o = pair
            .command(
                &pair.ns_b,
                &[
                    "run",
                    "--iface",
                    &pair.if_b,
                    "--scan-only",
                    "--save-network",
                    twin.to_str().unwrap(),
                    // The reference's crystal against true time cannot be measured here (the
                    // segment's true time is this host's clock, the master's own, and the
                    // figure measured against it is ~10 ppm off, see the report); the preset's
                    // is given, the others are the twin's measurement against it.
                    "--reference-ppm",
                    "12.4",
                ],
            )
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
fn a_twin_saved_after_a_run_has_the_reference_crystal_from_the_cyclic_phase() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let Some(pair) = NetPair::new("tr") else {
        return;
    };
    let dir = tmp("twin-run");
    let twin = dir.join("twin.toml");
    let _served = pair.serve(&[]);
    let o = pair
        .command(
            &pair.ns_b,
            &[
                "run",
                "--iface",
                &pair.if_b,
                "--method",
                "median-fit",
                "--duration",
                "12",
                "--timeout-us",
                "100000",
                "--save-network",
                twin.to_str().unwrap(),
                "--json",
            ],
        )
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

/// Issue 14, acceptance 3 and 4's refusal: send-time control on the real path.
mod send_control {
    use super::*;

    /// Spinning and sleeping cycles side by side in one run over the veth pair (odd cycles
    /// spin 50 us before their instant, even ones sleep to it): both measured on the same
    /// host at the same moments; the ratio and the CPU the spinning cost are printed (a
    /// figure of this host, not asserted: no timing is).
    #[test]
    fn spinning_and_sleeping_cycles_side_by_side_over_the_veth_pair() {
        let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
        let Some(pair) = NetPair::new("s") else {
            return;
        };
        let _served = pair.serve(&[]);
        let o = pair
            .command(
                &pair.ns_b,
                &[
                    "run",
                    "--iface",
                    &pair.if_b,
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
                ],
            )
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

    /// A veth has no hardware transmit timestamps: `--tx-stamp hardware` is refused before
    /// anything is sent, naming what the driver lacks as `ethtool -T` reports it (the
    /// capabilities are the kernel's ETHTOOL_GET_TS_INFO answer); a transmit stamp for a
    /// bus-shift method is refused too (it writes its send time into the frame before the
    /// frame leaves).
    #[test]
    fn hardware_tx_stamps_are_refused_on_veth_naming_what_is_missing() {
        let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
        let Some(pair) = NetPair::new("h") else {
            return;
        };
        // Independent truth: ethtool's own reading of the driver (.ci/run installs it).
        match Command::new("ip")
            .args(["netns", "exec", &pair.ns_b, "ethtool", "-T", &pair.if_b])
            .output()
        {
            Ok(o) if o.status.success() => {
                let t = String::from_utf8_lossy(&o.stdout);
                assert!(t.contains("software-transmit"), "{t}");
                assert!(!t.contains("hardware-transmit"), "{t}");
                assert!(t.contains("PTP Hardware Clock: none"), "{t}");
            }
            other => {
                assert!(
                    std::env::var_os("CI").is_none(),
                    "CI has ethtool: {other:?}"
                );
                println!("(no ethtool here: the veth's capabilities are not checked against it)");
            }
        }
        for (method, mode, want) in [
            ("median-fit", "hardware", "SOF_TIMESTAMPING_TX_HARDWARE"),
            ("median-fit", "hardware", "PTP Hardware Clock"),
            ("bus-shift", "software", "bus-shift method"),
            ("dcm-bus-shift", "hardware", "bus-shift method"),
        ] {
            let t0 = Instant::now();
            let o = pair
                .command(
                    &pair.ns_b,
                    &[
                        "run",
                        "--iface",
                        &pair.if_b,
                        "--method",
                        method,
                        "--tx-stamp",
                        mode,
                        "--duration",
                        "2",
                    ],
                )
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
    fn txtime_is_refused_naming_the_missing_piece() {
        let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
        let Some(pair) = NetPair::new("t") else {
            return;
        };
        let o = pair
            .command(
                &pair.ns_b,
                &[
                    "run",
                    "--iface",
                    &pair.if_b,
                    "--send",
                    "txtime",
                    "--duration",
                    "2",
                ],
            )
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
}
