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

/// A pseudo-terminal: its master end, and the path of its slave end.
fn pty() -> (std::fs::File, String) {
    use std::os::fd::FromRawFd;
    // SAFETY: plain FFI calls; the descriptor is owned by the File from here on; ptsname_r
    // writes at most the buffer's length, NUL-terminated.
    unsafe {
        let fd = libc::posix_openpt(libc::O_RDWR | libc::O_NOCTTY | libc::O_CLOEXEC);
        assert!(fd >= 0, "posix_openpt: {}", std::io::Error::last_os_error());
        let master = std::fs::File::from_raw_fd(fd);
        assert_eq!(libc::grantpt(fd), 0);
        assert_eq!(libc::unlockpt(fd), 0);
        let mut name = [0 as libc::c_char; 128];
        assert_eq!(libc::ptsname_r(fd, name.as_mut_ptr(), name.len()), 0);
        let name = std::ffi::CStr::from_ptr(name.as_ptr());
        (master, name.to_string_lossy().into_owned())
    }
}

/// Waits up to `limit` for `path` to hold a whole line; its text.
fn line_in(path: &std::path::Path, limit: Duration) -> Option<String> {
    let until = Instant::now() + limit;
    loop {
        if let Ok(t) = std::fs::read_to_string(path)
            && t.ends_with('\n')
        {
            return Some(t.trim().to_string());
        }
        if Instant::now() >= until {
            return None;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// An interactive COMMAND reads the terminal serve was started from. A shell in a session of
/// its own on a pseudo-terminal (its controlling terminal, as a login's) runs serve, then
/// reads a line itself: serve hands the terminal to COMMAND's process group, COMMAND reads
/// the first line, and serve takes the terminal back when COMMAND ends, so that the shell
/// reads the second. Before, COMMAND's read from the background stopped it (SIGTTIN) and
/// serve served on for ever; without the terminal taken back the shell would stop the same way.
#[test]
#[ignore = "needs network namespaces (root or unprivileged user namespaces)"]
fn an_interactive_command_reads_serve_s_terminal_which_serve_takes_back() {
    use std::io::Write;
    use std::os::unix::fs::OpenOptionsExt;
    use std::os::unix::process::CommandExt;
    let dir = tmp("terminal");
    let f = |name: &str| dir.join(name).display().to_string();
    let inner = format!(
        "echo $$ > {}; read a; echo \"$a\" > {}",
        f("inner.pid"),
        f("inner")
    );
    let script = format!(
        "{} serve --preset paper-2024 --quiet --sandbox -- sh -c '{inner}' > {} 2> {}; echo $? > {}; read b; echo \"$b\" > {}",
        ecsync(),
        f("serve.out"),
        f("serve.err"),
        f("serve.code"),
        f("outer")
    );
    let (mut master, slave) = pty();
    let tty = || {
        std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .custom_flags(libc::O_NOCTTY)
            .open(&slave)
            .unwrap()
    };
    let mut shell = std::process::Command::new("sh");
    shell
        .args(["-c", &script])
        .stdin(tty())
        .stdout(tty())
        .stderr(tty());
    // SAFETY: setsid and ioctl are async-signal-safe; stdin is the slave end by now.
    unsafe {
        shell.pre_exec(|| {
            if libc::setsid() < 0 || libc::ioctl(0, libc::TIOCSCTTY, 0) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
    let mut shell = shell.spawn().unwrap();
    // The echo of what is typed, read away so that the terminal never fills.
    let mut echo = master.try_clone().unwrap();
    std::thread::spawn(move || std::io::copy(&mut echo, &mut std::io::sink()));
    master.write_all(b"one\n").unwrap();
    let kill_all = |shell: &mut std::process::Child| {
        let mut groups = vec![shell.id() as i32];
        groups.extend(
            line_in(&dir.join("inner.pid"), Duration::ZERO).map(|p| p.parse::<i32>().unwrap()),
        );
        for g in groups {
            // SAFETY: plain FFI call on the test's own process groups (the shell's, serve in
            // it; COMMAND's).
            unsafe { libc::kill(-g, libc::SIGKILL) };
        }
        let _ = shell.wait();
    };
    let Some(read) = line_in(&dir.join("inner"), Duration::from_secs(60)) else {
        kill_all(&mut shell);
        panic!(
            "COMMAND did not read the terminal (stopped by SIGTTIN?); this test {NEEDS_NS}: {}",
            std::fs::read_to_string(dir.join("serve.err")).unwrap_or_default()
        );
    };
    assert_eq!(read, "one");
    let code = line_in(&dir.join("serve.code"), Duration::from_secs(30));
    master.write_all(b"two\n").unwrap();
    let outer = line_in(&dir.join("outer"), Duration::from_secs(30));
    let err = std::fs::read_to_string(dir.join("serve.err")).unwrap_or_default();
    if outer.is_none() {
        kill_all(&mut shell);
    }
    assert_eq!(code.as_deref(), Some("0"), "{err}");
    assert_eq!(
        outer.as_deref(),
        Some("two"),
        "the shell did not read the terminal after serve (not taken back?): {err}"
    );
    let status = wait_at_most(&mut shell, Duration::from_secs(10));
    assert!(status.success(), "{status}: {err}");
}
