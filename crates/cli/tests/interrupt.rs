//! Ctrl-C (SIGINT) and SIGTERM end `compare` in every phase: during a large segment's
//! bring-up (nothing measured, nothing written) and during the cycles (what was measured is
//! written); the exit code is 128 + the signal, 130 after SIGINT, 143 after SIGTERM. The signal is sent when the progress lines (stderr is a pipe
//! here, so lines, not a bar) show the phase reached: an event, not a sleep.

use std::fmt::Write as _;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc::{Receiver, channel};
use std::time::{Duration, Instant};

fn ecsync() -> Command {
    Command::new(env!("CARGO_BIN_EXE_ecsync"))
}

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("ecsync-interrupt-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// `n` servo drives in a line (1 m cables, crystals spread over +-40 ppm), `cycle_us` cycle.
fn line(n: usize, cycle_us: u32) -> String {
    let mut t = String::from("[segment]\nseed = 5\n");
    for k in 0..n {
        let up = if k == 0 {
            "master".to_string()
        } else {
            format!("d{}", k - 1)
        };
        let _ = write!(
            t,
            "[[segment.slave]]\nname = \"d{k}\"\nmodel = \"servo-mii\"\nupstream = \"{up}\"\n{}cable_m = 1.0\nppm = {:.1}\n",
            if k == 0 { "" } else { "upstream_port = 1\n" },
            ((k * 37) % 81) as f64 - 40.0
        );
    }
    let _ = write!(
        t,
        "[run]\ncycle_us = {cycle_us}\nsync0_shift_pct = 85\nruns = 1\ncycles = 2000\nwarmup_s = 1\nmethods = [\"soem-pi\"]\n",
    );
    t
}

/// The child's stderr, line by line, on a channel (read on a thread, so the wait has a limit).
fn stderr_lines(child: &mut Child) -> Receiver<String> {
    let err = child.stderr.take().unwrap();
    let (tx, rx) = channel();
    std::thread::spawn(move || {
        for l in BufReader::new(err).lines().map_while(Result::ok) {
            if tx.send(l).is_err() {
                break;
            }
        }
    });
    rx
}

/// Waits (at most ten minutes: a limit against a hang, not a timing) for a line `want` accepts;
/// every line seen is kept in `seen`.
fn wait_for(rx: &Receiver<String>, seen: &mut Vec<String>, want: impl Fn(&str) -> bool) {
    let until = Instant::now() + Duration::from_secs(600);
    while Instant::now() < until {
        match rx.recv_timeout(Duration::from_secs(1)) {
            Ok(l) => {
                let hit = want(&l);
                seen.push(l);
                if hit {
                    return;
                }
            }
            Err(std::sync::mpsc::RecvTimeoutError::Timeout) => {}
            Err(_) => break,
        }
    }
    panic!("no such progress line; stderr:\n{}", seen.join("\n"));
}

fn signal(child: &Child, sig: i32) {
    // SAFETY: a signal to our own child, whose pid is valid until it is waited for.
    let rc = unsafe { libc::kill(child.id() as i32, sig) };
    assert_eq!(rc, 0);
}

fn json(p: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap()
}

/// Issue 30, edge 1: SIGINT, then SIGTERM, during the bring-up of a 5 000-drive line (20 ms
/// cycle; its bring-up takes a minute, far longer than the five seconds between progress
/// lines; a 2 000-drive line's took under five once its configuration went side by side) ends
/// it with exit 128 + the signal (130, then 143) and writes nothing; the progress lines named the bring-up's phase before.
#[test]
fn a_signal_during_a_large_bring_up_stops_it() {
    let dir = tmp("bringup");
    let cfg = dir.join("line-5000.toml");
    std::fs::write(&cfg, line(5000, 20_000)).unwrap();
    for (sig, name) in [(libc::SIGINT, "SIGINT"), (libc::SIGTERM, "SIGTERM")] {
        let out = dir.join(format!("out-{name}"));
        let mut child = ecsync()
            .args(["compare", "--config"])
            .arg(&cfg)
            .arg("--out")
            .arg(&out)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let rx = stderr_lines(&mut child);
        let mut seen = Vec::new();
        // A phase past the scan: the bring-up is under way (thousands of frames).
        wait_for(&rx, &mut seen, |l| {
            l.contains("bring-up: ") && !l.contains("bring-up: starting")
        });
        let t0 = Instant::now();
        signal(&child, sig);
        let status = child.wait().unwrap();
        let took = t0.elapsed();
        // Every line: the reader ends at the pipe's end, after the exit (what was in flight when
        // the child ended is read too; try_iter missed the last lines once under load).
        seen.extend(rx.iter());
        let e = seen.join("\n");
        assert_eq!(status.code(), Some(128 + sig), "{name}: {e}");
        assert!(
            e.contains("stopped during the bring-up") && e.contains("nothing written"),
            "{name}: {e}"
        );
        assert!(
            !e.contains("1 of 1 run up"),
            "{name}: the bring-up was done: {e}"
        );
        assert!(!out.join("summary.json").exists(), "{name}");
        // How long the stop took (printed, not asserted: a loaded machine decides it; the
        // bring-up looks at the flag before every exchange).
        eprintln!("{name} during the bring-up to exit: {took:?}");
    }
}

/// SIGINT once the cycles run stops a long comparison: exit 130, summary.json with
/// `interrupted: true` and the cycles done, the report written.
#[test]
fn ctrl_c_stops_and_keeps_what_was_measured() {
    let out = tmp("sigint");
    let mut child = ecsync()
        .args(["compare", "--runs", "2", "--cycles", "50000000"])
        .arg("--out")
        .arg(&out)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let rx = stderr_lines(&mut child);
    let mut seen = Vec::new();
    // A progress line whose count of cycles ("(done of total cycles)", the warm-up included)
    // is past every run's warm-up: the runs have recorded cycles. (A line that merely counts
    // can come during the warm-up on a loaded machine, and a warm-up interrupted records
    // nothing: `cycles_done` 0.)
    let asked = 8 * 2 * 50_000_000u64;
    wait_for(&rx, &mut seen, |l| {
        let count = l
            .rsplit_once('(')
            .and_then(|(_, c)| c.split_once(" cycles)"));
        count
            .and_then(|(c, _)| c.split_once(" of "))
            .and_then(|(d, t)| Some((d.parse::<u64>().ok()?, t.parse::<u64>().ok()?)))
            .is_some_and(|(done, total)| done > total.saturating_sub(asked))
    });
    let t0 = Instant::now();
    signal(&child, libc::SIGINT);
    let status = child.wait().unwrap();
    let took = t0.elapsed();
    seen.extend(rx.iter());
    let e = seen.join("\n");
    assert_eq!(status.code(), Some(130), "{e}");
    assert!(e.contains("interrupted"), "{e}");
    let j = json(&out.join("summary.json"));
    assert_eq!(j["interrupted"], true);
    let done = j["cycles_done"].as_u64().unwrap();
    assert!(done > 0 && done < 8 * 2 * 50_000_000, "{done}");
    assert!(
        j["warnings"]
            .as_array()
            .unwrap()
            .iter()
            .any(|w| w["kind"] == "interrupted")
    );
    assert!(out.join("report.html").exists());
    eprintln!("SIGINT to exit, report written: {took:?}");
}
