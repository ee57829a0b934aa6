//! `ecsync run` with a method against `ecsync serve`, checked against the segment's truth.

use super::*;

thread_local! {
    /// The wake-up p99 of the last `ecsync run` of this thread, us.
    static LAST_WAKE_P99_US: std::cell::Cell<f64> = const { std::cell::Cell::new(f64::NAN) };
    /// The largest send-to-wire delay of the last run's first ten cycles, us.
    static LAST_FIRST_TX_DELAY_US: std::cell::Cell<f64> = const { std::cell::Cell::new(f64::NAN) };
}

/// A first cycle's frame that sat this long between its timestamp and the wire says the host
/// stalled the send as the cyclic phase began: bus shift then writes the reference a master
/// time that old, and the ESC's time control loop learns from that step a clock period
/// deviation it takes seconds to unlearn (CI once: 54 us in cycle 0, the reference then ran
/// 16 ppm off the master for the whole 10 s run). Host noise, not the path: checked again.
const NOISY_FIRST_TX_DELAY_US: f64 = 20.0;

/// A wake-up p99 past this says the host, not the path, was in trouble: this shared VM has
/// phases in which an idle guest's 1 ms timer wakes a millisecond late one cycle in a hundred
/// (its quiet p99 is 80-150 us), and `serve`'s segment, which runs on the same cores in real
/// time, then takes its frames late as well.
const NOISY_HOST_P99_US: f64 = 400.0;

/// `ecsync run` with `method` for 10 s at 1 ms against `ecsync serve`, checked; once more if
/// the checks failed while the host was noisy (see [`NOISY_HOST_P99_US`]), and the second run
/// must pass them all.
pub(crate) fn run_method(pair: &NetPair, method: &str) {
    LAST_WAKE_P99_US.with(|c| c.set(f64::NAN));
    LAST_FIRST_TX_DELAY_US.with(|c| c.set(f64::NAN));
    let first = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        run_method_once(pair, method);
    }));
    if let Err(e) = first {
        let p99 = LAST_WAKE_P99_US.with(|c| c.get());
        let first_tx = LAST_FIRST_TX_DELAY_US.with(|c| c.get());
        if p99 > NOISY_HOST_P99_US || first_tx > NOISY_FIRST_TX_DELAY_US {
            println!(
                "{method}: the checks failed with the host's wake-up p99 at {p99:.0} us and its first cycles' largest send delay {first_tx:.0} us (noisy): once more"
            );
            run_method_once(pair, method);
        } else {
            std::panic::resume_unwind(e);
        }
    }
}

/// The values of column `name` of a `run --csv` file, rows with it blank left out.
pub(crate) fn csv_column(csv: &Path, name: &str) -> Vec<f64> {
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

/// `ecsync run` with `args` and `--summary summary` against the served segment, which must
/// succeed: its standard output and the summary.
fn run_with_summary(pair: &NetPair, args: &[&str], summary: &Path) -> (String, serde_json::Value) {
    let o = pair
        .run(args)
        .args(["--summary", summary.to_str().unwrap()])
        .output()
        .expect("ecsync run");
    let text = String::from_utf8_lossy(&o.stdout).into_owned();
    assert!(
        o.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let j = serde_json::from_str(&std::fs::read_to_string(summary).unwrap()).unwrap();
    (text, j)
}

fn run_method_once(pair: &NetPair, method: &str) {
    let dir = tmp(method);
    let csv = dir.join("cycles.csv");
    let t0 = Instant::now();
    let o = pair
        .run(&[
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
        ])
        .output()
        .expect("run ecsync run");
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "ecsync run --method {method}: {stderr}");
    let j: serde_json::Value = serde_json::from_slice(&o.stdout).expect("JSON summary");
    let p99 = j["wake_latency"]["p99_us"].as_f64().unwrap_or(f64::NAN);
    LAST_WAKE_P99_US.with(|c| c.set(p99));
    let first_tx_us = csv_column(&csv, "tx_delay_ns")
        .iter()
        .take(10)
        .fold(0.0f64, |m, &d| m.max(d / 1000.0));
    LAST_FIRST_TX_DELAY_US.with(|c| c.set(first_tx_us));
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
    // IgH's way writes the master's time too (every second cycle): the same checks.
    if method == "bus-shift" || method == "igh-app-time" {
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
            "{method}: reference vs master drift {drift_ppm:.3} ppm, median |t_ra - t_ms| {err_abs:.0} ns, median |0x092C| {diff_abs:.0} ns"
        );
        assert!(
            drift_ppm.abs() < 3.0,
            "{method}: the reference drifts from the master by {drift_ppm:.2} ppm"
        );
        assert!(
            err_abs < 20_000.0,
            "{method}: median |t_ra - t_ms| {err_abs} ns"
        );
        assert!(
            diff_abs < 10_000.0,
            "{method}: median |0x092C| {diff_abs} ns"
        );
    } else {
        // The lock threshold (100 ns) in 99% of the cycles, never beyond a microsecond. (The
        // frames come at the host's irregular instants and every compare meets the MII ports'
        // 40 ns receive clock at another phase: single cycles show 80-120 ns.) DCM's bus shift
        // moves the reference's time while it pulls in (10 s here, from the tens of
        // microseconds the host's send latency puts the first frames off), which the slaves
        // follow within a hundred ns or so: twice the threshold.
        // Since MII stamps sit on the crystals' 40 ns grids (issue 32) a slave's |0x092C| moves
        // in those cells: Table 1's rS-IS MMax of the master-shift methods is 126 ns (the
        // letter's 132), and a run over veth reached p99 126 ns for snap (CI): four cells.
        let p99_bound = if method == "dcm-bus-shift" {
            200.0
        } else {
            160.0
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
    let kind: ecsync_dc::MethodKind = method.parse().unwrap();
    if !kind.is_master_shift() {
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
#[ignore = "needs network namespaces (root)"]
fn a_run_that_ends_in_its_method_s_initialisation_says_so_not_nan() {
    // 0.5 s of cycles against a 2 s initialisation: the method never measured an M-rS (the
    // summary's n is 0); the text said `M-rS NaN NaN NaN NaN` (as after a Ctrl-C in the
    // first second of the cyclic phase).
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let pair = NetPair::new("i");
    let dir = tmp("init");
    let _served = pair.serve(&[]);
    let (text, j) = run_with_summary(
        &pair,
        &["--method", "median", "--init-s", "2", "--duration", "0.5"],
        &dir.join("s.json"),
    );
    assert_eq!(j["m_rs"]["n"], 0, "{j}");
    assert!(j["rs_is"]["n"].as_u64().unwrap() > 0, "{j}");
    assert!(!text.contains("NaN"), "{text}");
    assert!(
        text.contains("M-rS                   none measured: the run stopped before the method's initialisation (--init-s) ended"),
        "{text}"
    );
}

#[test]
#[ignore = "needs network namespaces (root)"]
fn a_dcm_run_not_in_sync_at_its_end_says_so() {
    // Half a second of dcm-bus-shift, shorter than its in-sync hold (1.5 s): its controller
    // cannot be in sync at the end, nor at any cycle before it, and run said nothing of it
    // where compare warns; then it said only the end's state, which does not tell "never
    // locked" from "lost it at the end". snap has no controller to be in sync: no warning.
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let pair = NetPair::new("w");
    let dir = tmp("dcm-warn");
    let _served = pair.serve(&[]);
    for (method, warned) in [("dcm-bus-shift", true), ("snap", false)] {
        let (text, j) = run_with_summary(
            &pair,
            &["--method", method, "--duration", "0.5"],
            &dir.join(format!("{method}.json")),
        );
        if warned {
            // The controller's own state at the end, which the warning reports, and over the
            // run: every cycle run (none skipped or not) out of sync, by the hold time alone.
            let c = &j["controller"];
            assert_eq!(c["in_sync"], false, "{method}: {j}");
            assert_eq!(c["cycles_run"], j["cycles"], "{method}: {j}");
            assert_eq!(c["in_sync_share"], 0.0, "{method}: {j}");
            assert!(c["first_in_sync_s"].is_null(), "{method}: {j}");
            assert_eq!(c["sync_losses"], 0, "{method}: {j}");
            let never = format!(
                "it never reported in sync in the {} cycles it ran",
                j["cycles"]
            );
            assert!(text.contains(&never), "{method}: {text}");
        } else {
            assert!(j["controller"].is_null(), "{method}: {j}");
        }
        let says =
            format!("Warning: {method}'s controller did not report in sync at the end of the run");
        assert_eq!(text.contains(&says), warned, "{method}: {text}");
        assert_eq!(j["warnings"].is_array(), warned, "{method}: {j}");
    }
}

#[test]
#[ignore = "needs network namespaces (root)"]
fn a_dcm_bus_shift_run_pulling_in_past_its_slew_limit_says_so() {
    // The served segment is paper-2024's: its reference's crystal is 12.4 ppm from the host's
    // clock, which serve and run both read, where compare's master sits at 13.3 ppm (0.9 ppm
    // apart). dcm-bus-shift's proportional part is limited to 5 ppm, so it must ramp its
    // learnt drift (2 ppm/s) past the limit and pull the phase in at it: on this VM it first
    // reported in sync after 14.5 s (11.1 s in virtual time with compare --master-ppm 0). After
    // 8 s it has learnt more than the limit and is still pulling in, and the warning says why.
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let pair = NetPair::new("p");
    let dir = tmp("dcm-pull-in");
    let _served = pair.serve(&[]);
    let (text, j) = run_with_summary(
        &pair,
        &["--method", "dcm-bus-shift", "--duration", "8"],
        &dir.join("s.json"),
    );
    let c = &j["controller"];
    let drift = c["drift_ppm"].as_f64().unwrap();
    // The truth: 12.4 ppm; the ramp overshoots it while the phase comes back (by 6 ppm in
    // virtual time).
    assert!((5.0..25.0).contains(&drift), "learnt {drift} ppm: {j}");
    assert_eq!(c["in_sync"], false, "{j}");
    assert_eq!(c["limits"]["max_slew_ppm"], 5.0, "{j}");
    let slew = format!(
        "likely why: the reference's crystal runs about {drift:.1} ppm from this host's clock (the drift it learnt), beyond its 5 ppm slew limit"
    );
    assert!(text.contains(&slew), "{text}");
    println!(
        "dcm-bus-shift after 8 s: learnt {drift:.2} ppm, filtered error {:.1} us, in sync {:.1} %, wake-up p99.9 {:.0} us",
        c["filtered_error_ns"].as_f64().unwrap() / 1e3,
        c["in_sync_share"].as_f64().unwrap() * 100.0,
        j["wake_latency"]["p999_us"].as_f64().unwrap()
    );
}
