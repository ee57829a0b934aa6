//! Signals and `serve --sandbox -- COMMAND`: a SIGTERM to serve reaches COMMAND's whole
//! process group, which is killed if it outlives the signal by half a second (serve exits
//! within a second, whatever COMMAND does); and `ecsync run` as COMMAND, stopped in its
//! bring-up, says what it had measured and exits with 128 + the signal. Ignored unless asked
//! for, as the other sandbox tests (a machine may refuse namespaces).

#[path = "common/sandbox.rs"]
mod sandbox_common;

use sandbox_common::{NEEDS_NS, drain, ecsync, sandboxed, tmp, wait_at_most};
use std::io::{BufRead, BufReader};
use std::process::{Child, Stdio};
use std::time::{Duration, Instant};

#[test]
#[ignore = "needs network namespaces (root or unprivileged user namespaces)"]
fn a_sigterm_to_serve_reaches_the_command_and_its_code_is_serve_s() {
    let (mut child, err) = serving(&["sleep", "60"]);
    let t0 = Instant::now();
    // SAFETY: plain FFI call on the pid of a child not yet waited for.
    assert_eq!(unsafe { libc::kill(child.id() as i32, libc::SIGTERM) }, 0);
    let status = wait_at_most(&mut child, Duration::from_secs(20));
    let e = err.join().unwrap();
    assert_eq!(status.code(), Some(128 + libc::SIGTERM), "{e}");
    assert!(t0.elapsed() < Duration::from_secs(5), "{:?}", t0.elapsed());
    assert!(e.contains("COMMAND exited: signal: 15"), "{e}");
}

/// `serve --sandbox -- command` started, up to its ready line: the child and its stderr.
fn serving(command: &[&str]) -> (Child, std::thread::JoinHandle<String>) {
    let mut child = sandboxed(&[], command)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let err = drain(child.stderr.take());
    let mut first = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut first)
        .unwrap();
    if first.is_empty() {
        let status = wait_at_most(&mut child, Duration::from_secs(10));
        panic!(
            "no ready line ({status}); this test {NEEDS_NS}: {}",
            err.join().unwrap()
        );
    }
    let v: serde_json::Value = serde_json::from_str(&first).expect("the ready line");
    assert_eq!(v["pid"].as_u64(), Some(u64::from(child.id())));
    (child, err)
}

/// Whether process `pid` has ended (gone, or a zombie nobody reaped yet).
fn ended(pid: u32) -> bool {
    match std::fs::read_to_string(format!("/proc/{pid}/stat")) {
        // The state follows the command's name in parentheses.
        Ok(stat) => stat
            .rsplit_once(") ")
            .is_some_and(|(_, rest)| rest.starts_with('Z') || rest.starts_with('X')),
        Err(_) => true,
    }
}

/// A SIGTERM to serve alone, with a COMMAND that ignores it and has a child of its own: serve
/// does not wait ten seconds for COMMAND (as it did) but kills COMMAND's process group half a
/// second after passing the signal on, the child with it, and exits with COMMAND's code.
#[test]
#[ignore = "needs network namespaces (root or unprivileged user namespaces)"]
fn a_sigterm_to_serve_stops_a_command_that_ignores_it_and_its_children() {
    let dir = tmp("ignores-sigterm");
    let pid_file = dir.join("child.pid");
    // The shell ignores SIGTERM, and so does its child (ignored signals are inherited); the
    // pid file is written before the shell's `wait`, and read once it is whole.
    let script = format!(
        "trap '' TERM; sleep 600 & echo $! > {0}.new; mv {0}.new {0}; wait",
        pid_file.display()
    );
    let (mut child, err) = serving(&["sh", "-c", &script]);
    let until = Instant::now() + Duration::from_secs(20);
    let grandchild: u32 = loop {
        if let Ok(t) = std::fs::read_to_string(&pid_file) {
            break t.trim().parse().unwrap();
        }
        assert!(Instant::now() < until, "no pid file from COMMAND");
        std::thread::sleep(Duration::from_millis(20));
    };
    let t0 = Instant::now();
    // SAFETY: plain FFI call on the pid of a child not yet waited for.
    assert_eq!(unsafe { libc::kill(child.id() as i32, libc::SIGTERM) }, 0);
    let status = wait_at_most(&mut child, Duration::from_secs(30));
    let took = t0.elapsed();
    let e = err.join().unwrap();
    assert_eq!(status.code(), Some(128 + libc::SIGKILL), "{e}");
    assert!(e.contains("killed with its process group"), "{e}");
    // Not waited for ten seconds (a bound far above the half second, for a loaded machine).
    assert!(took < Duration::from_secs(5), "{took:?}: {e}");
    // The COMMAND's child ended with it (a signal in flight takes a moment to land).
    let until = Instant::now() + Duration::from_secs(10);
    while !ended(grandchild) && Instant::now() < until {
        std::thread::sleep(Duration::from_millis(20));
    }
    let left = ended(grandchild);
    if !left {
        // SAFETY: plain FFI call; the test's own leftover.
        unsafe { libc::kill(grandchild as i32, libc::SIGKILL) };
    }
    assert!(left, "COMMAND's child {grandchild} outlived serve: {e}");
    println!("SIGTERM to exit: {took:?}");
}

/// `ecsync run` stopped by SIGINT, then SIGTERM, in its bring-up's static drift phase (the
/// propagation delays measured before it): it says which phases were done and that the
/// delays were measured (before: "nothing measured"), and exits 130, then 143.
#[test]
#[ignore = "needs network namespaces (root or unprivileged user namespaces)"]
fn a_run_stopped_in_its_bring_up_says_what_it_had_measured() {
    for (sig, name) in [(libc::SIGINT, "SIGINT"), (libc::SIGTERM, "SIGTERM")] {
        let dir = tmp(&format!("run-stopped-{name}"));
        let pid_file = dir.join("run.pid");
        // Static drift long enough to be stopped in (millions of frames); the shell passes
        // run's exit code on as its own, and serve passes the shell's.
        let script = format!(
            "{} run --iface \"$ECSYNC_IFACE\" --priority 0 --static-drift 50000000 & echo $! > {1}.new; mv {1}.new {1}; wait $!",
            ecsync(),
            pid_file.display()
        );
        let mut child = sandboxed(&[], &["sh", "-c", &script])
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let (tx, rx) = std::sync::mpsc::channel();
        let err = child.stderr.take().unwrap();
        std::thread::spawn(move || {
            for l in BufReader::new(err).lines().map_while(Result::ok) {
                let _ = tx.send(l);
            }
        });
        // The drift phase's progress line (a limit against a hang, not a timing).
        let mut seen = Vec::new();
        let until = Instant::now() + Duration::from_secs(120);
        while !seen.iter().any(|l: &String| l.trim() == "drift") {
            assert!(
                Instant::now() < until,
                "no drift phase; this test {NEEDS_NS}: {}",
                seen.join("\n")
            );
            if let Ok(l) = rx.recv_timeout(Duration::from_secs(1)) {
                seen.push(l);
            }
        }
        let pid: i32 = std::fs::read_to_string(&pid_file)
            .unwrap()
            .trim()
            .parse()
            .unwrap();
        // SAFETY: plain FFI call; `ecsync run` waits in the shell, not yet reaped.
        assert_eq!(unsafe { libc::kill(pid, sig) }, 0);
        let status = wait_at_most(&mut child, Duration::from_secs(60));
        seen.extend(rx.iter());
        let e = seen.join("\n");
        assert_eq!(status.code(), Some(128 + sig), "{name}: {e}");
        assert!(
            e.contains("stopped during the bring-up, in its drift phase, after scan, identify, delays, offsets")
                && e.contains("the propagation delays"),
            "{name}: {e}"
        );
        assert!(!e.contains("nothing measured"), "{name}: {e}");
    }
}
