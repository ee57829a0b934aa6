//! `ecsync serve --sandbox -- COMMAND`: the segment served in a private network made by the
//! process itself (a network namespace, in a user namespace when unprivileged), COMMAND run on
//! the other end of a veth pair with `ECSYNC_IFACE`, its exit code passed through, the ready
//! line first on stdout; as the current user (root in CI) and as `nobody`, with a shell, SOEM
//! (pysoem) and ethercrab as COMMAND.
//!
//! The tests that make namespaces are ignored unless asked for (a machine may refuse user
//! namespaces: sysctls, AppArmor, a container's seccomp profile), and asked for they fail
//! naming what was refused; the ones as `nobody` need setpriv (util-linux) and root to become
//! nobody, the SOEM ones a Python with pysoem (`ECSYNC_PYSOEM_PYTHON`; as nobody it must be one
//! that nobody can run: .ci/run makes it so).

// The ring of issue 34 and its checks, as the real-network test has them too.
#[path = "common/ring.rs"]
mod ring;
// The binary, folders, `serve --sandbox`, waiting with a limit.
#[path = "common/sandbox.rs"]
mod sandbox_common;

use std::path::{Path, PathBuf};
use std::process::{Command, ExitStatus, Stdio};
use std::sync::Mutex;
use std::time::{Duration, Instant};

use sandbox_common::{NEEDS_NS, drain, ecsync, sandboxed, tmp, wait_at_most};

/// The masters that run cycles in real time take the machine's cores one at a time.
static TIMED: Mutex<()> = Mutex::new(());

fn script(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/pysoem")
        .join(name)
}

/// What a command did: its status, stdout, stderr, and how long it took.
struct Ran {
    status: ExitStatus,
    stdout: String,
    stderr: String,
    took: Duration,
}

/// Runs `cmd` to its end, killed after `limit` (a test must not hang); a command that cannot
/// start, or that the sandbox could not be made for, fails the test with the reason.
fn run(mut cmd: Command, limit: Duration) -> Ran {
    let t0 = Instant::now();
    let mut child = cmd
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap_or_else(|e| panic!("cannot start {cmd:?}: {e}"));
    let (out, err) = (drain(child.stdout.take()), drain(child.stderr.take()));
    let status = wait_at_most(&mut child, limit);
    let r = Ran {
        status,
        stdout: out.join().unwrap(),
        stderr: err.join().unwrap(),
        took: t0.elapsed(),
    };
    assert!(
        !r.stderr.contains("--sandbox: cannot make"),
        "this test {NEEDS_NS}, and this machine refused: {}",
        r.stderr
    );
    assert!(t0.elapsed() < limit, "killed after {limit:?}: {}", r.stderr);
    r
}

/// nobody's uid and gid.
fn nobody() -> (u32, u32) {
    let name = std::ffi::CString::new("nobody").unwrap();
    // SAFETY: `name` is a live C string; getpwnam returns null or a pointer into static
    // storage, read at once on this thread.
    let pw = unsafe { libc::getpwnam(name.as_ptr()) };
    assert!(!pw.is_null(), "this test needs a user nobody");
    // SAFETY: checked non-null above.
    unsafe { ((*pw).pw_uid, (*pw).pw_gid) }
}

/// `program args...` as nobody (setpriv, util-linux; needs root), in a directory nobody can
/// enter, with HOME there.
fn as_nobody(program: &str, dir: &Path) -> Command {
    let ok = Command::new("setpriv")
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success());
    assert!(ok, "this test needs setpriv (util-linux)");
    let (uid, gid) = nobody();
    let probe = Command::new("setpriv")
        .args([&format!("--reuid={uid}"), &format!("--regid={gid}")])
        .args(["--clear-groups", "true"])
        .output()
        .unwrap();
    assert!(
        probe.status.success(),
        "this test needs setpriv and root to become nobody: {}",
        String::from_utf8_lossy(&probe.stderr)
    );
    let mut c = Command::new("setpriv");
    c.args([&format!("--reuid={uid}"), &format!("--regid={gid}")])
        .arg("--clear-groups")
        .arg(program)
        .current_dir(dir)
        .env("HOME", dir);
    c
}

/// `path` if nobody can read (and run) it where it is, else a copy of it in `dir` that nobody
/// can (a clone under a private home).
fn for_nobody(path: &Path, dir: &Path) -> PathBuf {
    let (uid, gid) = nobody();
    let readable = Command::new("setpriv")
        .args([&format!("--reuid={uid}"), &format!("--regid={gid}")])
        .args(["--clear-groups", "test", "-r"])
        .arg(path)
        .status()
        .is_ok_and(|s| s.success());
    if readable {
        return path.to_path_buf();
    }
    use std::os::unix::fs::PermissionsExt;
    let copy = dir.join(path.file_name().unwrap());
    std::fs::copy(path, &copy).unwrap();
    std::fs::set_permissions(&copy, std::fs::Permissions::from_mode(0o755)).unwrap();
    copy
}

/// A Python with pysoem (`ECSYNC_PYSOEM_PYTHON`, else python3) that `check` runs: the test
/// panics saying how to get one where there is none.
fn python(check: impl Fn(&str) -> Command) -> String {
    let py = std::env::var("ECSYNC_PYSOEM_PYTHON").unwrap_or_else(|_| "python3".into());
    let ok = check(&py)
        .args(["-c", "import pysoem"])
        .output()
        .is_ok_and(|o| o.status.success());
    assert!(
        ok,
        "this test needs pysoem, and {py} has none for the user that runs it: pip install pysoem, or set ECSYNC_PYSOEM_PYTHON to a Python that has it (.ci/run makes a venv any user can run)"
    );
    py
}

fn code(r: &Ran) -> Option<i32> {
    r.status.code()
}

/// The number in `s` between `before` and `after` (the first such).
fn number_between(s: &str, before: &str, after: &str) -> Option<f64> {
    let rest = s.split(before).nth(1)?;
    rest.split(after).next()?.trim().parse().ok()
}

/// `soem_cycle.py`'s receive timeout (its default), us.
const SOEM_RECV_TIMEOUT_US: f64 = 3000.0;

/// The cycles `soem_cycle.py` failed on with a wrong working counter that serve's own host
/// explains, by what serve measured of itself; 0 unless it explains all. Each such cycle's
/// frame never came back within the receive timeout (a reply with a wrong counter is no
/// stall's), serve sent at least as many replies more than 1 ms past their wire time (its
/// stalls), and its latest at least the timeout late. CI: a reply 4 060 us late lost one
/// frame, the master's loop on time; at a load of 5, replies up to 4.3 ms late lost two.
/// A segment or master that gets a working counter wrong, or loses a frame while serve kept
/// time, still fails.
fn timeouts_from_serve_s_stalls(r: &Ran) -> u64 {
    let e = &r.stderr;
    let failed = "soem_cycle: FAILED: ";
    let wrong = number_between(e, failed, " cycles with a wrong working counter");
    let no_reply = number_between(e, "wrong working counter, ", " of them without a reply");
    let serve = e.split("this host sent ").nth(1).unwrap_or_default();
    let stalled = number_between(serve, " us late, ", " more than 1000 us");
    let latest_us = number_between(serve, ", the latest ", " us late");
    let (Some(wrong), Some(no_reply), Some(stalled), Some(latest_us)) =
        (wrong, no_reply, stalled, latest_us)
    else {
        return 0;
    };
    let explained =
        wrong >= 1.0 && no_reply == wrong && stalled >= wrong && latest_us >= SOEM_RECV_TIMEOUT_US;
    if !explained {
        return 0;
    }
    println!(
        "{wrong} frames lost to serve's own host stalls ({stalled} replies over 1 ms late, the latest {latest_us} us): not the master's"
    );
    wrong as u64
}

/// What serve's stalls explain, on the lines soem_cycle and serve print: every cycle lost
/// without a reply, as many replies over 1 ms late, the latest past the 3 ms timeout; less
/// explains nothing (the test then fails on the master's exit code).
#[test]
fn timeouts_are_serve_s_only_where_its_own_stalls_cover_them() {
    use std::os::unix::process::ExitStatusExt;
    let ran = |wrong: u32, no_reply: u32, stalled: u32, latest_us: f64| Ran {
        status: ExitStatus::from_raw(1 << 8),
        stdout: String::new(),
        stderr: format!(
            "soem_cycle: FAILED: {wrong} cycles with a wrong working counter, {no_reply} of them without a reply within 3000 us (the first: cycle 7, wkc -1, expected 18)\n\
             replies at wire time: 9000; this host sent 40 of them more than 50 us late, {stalled} more than 1000 us, the latest {latest_us:.1} us late (the host's lateness, not the model's)\n"
        ),
        took: Duration::ZERO,
    };
    assert_eq!(timeouts_from_serve_s_stalls(&ran(2, 2, 3, 4300.0)), 2);
    assert_eq!(timeouts_from_serve_s_stalls(&ran(1, 1, 1, 3000.0)), 1);
    // A reply with a wrong counter, too few stalls, none as late as the timeout.
    assert_eq!(timeouts_from_serve_s_stalls(&ran(2, 1, 3, 4300.0)), 0);
    assert_eq!(timeouts_from_serve_s_stalls(&ran(2, 2, 1, 4300.0)), 0);
    assert_eq!(timeouts_from_serve_s_stalls(&ran(2, 2, 3, 2900.0)), 0);
}

/// Exit 0, or the timeouts serve's own stalls explain.
fn assert_master_passed(r: &Ran) {
    if timeouts_from_serve_s_stalls(r) == 0 {
        assert_eq!(code(r), Some(0), "{}", r.stderr);
    }
}

/// A ring's second interface is refused before anything is opened where it cannot be one:
/// the same as `--iface` (serve and run), or on a segment that is no ring (serve).
#[test]
fn a_ring_interface_that_cannot_be_one_is_refused_naming_the_fix() {
    let dir = tmp("ring-refused");
    let ring = dir.join("ring.toml");
    std::fs::write(&ring, ring::ring_toml()).unwrap();
    let ring = ring.to_str().unwrap();
    for (args, says) in [
        (
            &["run", "--iface", "a0", "--ring-iface", "a0"][..],
            "that is --iface",
        ),
        (
            &[
                "serve",
                "--iface",
                "a0",
                "--ring-iface",
                "a0",
                "--config",
                ring,
            ][..],
            "that is --iface",
        ),
        (
            &["serve", "--iface", "a0", "--ring-iface", "a1"][..],
            "the segment is no ring; fix",
        ),
    ] {
        let o = Command::new(ecsync()).args(args).output().unwrap();
        let e = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{args:?}: {e}");
        assert!(
            e.contains("--ring-iface a") && e.contains(says),
            "{args:?}: {e}"
        );
    }
}

#[test]
fn serve_needs_an_interface_or_the_sandbox_and_the_sandbox_a_command() {
    for (args, says) in [
        (&["serve"][..], "--iface"),
        (&["serve", "--sandbox"][..], "COMMAND"),
        (&["serve", "--iface", "x", "--", "true"][..], "--sandbox"),
    ] {
        let o = Command::new(ecsync()).args(args).output().unwrap();
        let e = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {e}");
        assert!(e.contains(says), "{args:?}: {e}");
    }
}

#[test]
#[ignore = "needs network namespaces (root or unprivileged user namespaces)"]
fn the_sandbox_passes_the_command_s_exit_code_through() {
    let r = run(
        sandboxed(&[], &["sh", "-c", "exit 3"]),
        Duration::from_secs(30),
    );
    assert_eq!(code(&r), Some(3), "{}", r.stderr);
    println!("exit 3 passed through in {:?}", r.took);
    let r = run(
        sandboxed(&[], &["sh", "-c", "kill -TERM $$"]),
        Duration::from_secs(30),
    );
    assert_eq!(code(&r), Some(128 + libc::SIGTERM), "{}", r.stderr);
    let r = run(
        sandboxed(&[], &["ecsync-no-such-command"]),
        Duration::from_secs(30),
    );
    assert_eq!(code(&r), Some(127), "{}", r.stderr);
    assert!(r.stderr.contains("cannot run ecsync-no-such-command"));
}

/// The ready line is the first line on stdout (COMMAND starts after it), and the same in
/// --ready-file; COMMAND finds its interface up, and the sandbox's sysfs shows the sandbox's
/// interfaces, not the host's.
fn ready_line_then_interface_up(r: &Ran, ready_file: &Path) {
    assert_eq!(code(r), Some(0), "{}", r.stderr);
    let mut lines = r.stdout.lines();
    let first = lines.next().expect("a ready line");
    let v: serde_json::Value = serde_json::from_str(first).expect("the ready line is JSON");
    assert_eq!(v["event"], "ready", "{first}");
    assert_eq!(v["iface"], "ecsync0", "{first}");
    assert_eq!(v["master_iface"], "master0", "{first}");
    assert_eq!(v["slaves"], 6, "{first}");
    assert_eq!(v["preset"], "paper-2024", "{first}");
    assert!(v["pid"].as_u64().is_some_and(|p| p > 0), "{first}");
    assert!(first.starts_with(r#"{"event":"ready","#), "{first}");
    assert_eq!(
        std::fs::read_to_string(ready_file).unwrap(),
        format!("{first}\n")
    );
    assert_eq!(lines.next(), Some("up"), "{}", r.stdout);
    let mut ifaces: Vec<&str> = lines.collect();
    ifaces.sort();
    assert_eq!(ifaces, ["ecsync0", "lo", "master0"], "{}", r.stdout);
}

const CHECK_IFACE: &str = "cat /sys/class/net/$ECSYNC_IFACE/operstate && ls /sys/class/net";

#[test]
#[ignore = "needs network namespaces (root or unprivileged user namespaces)"]
fn the_command_finds_its_interface_up_after_the_ready_line() {
    let dir = tmp("ready");
    let ready = dir.join("ready.json");
    let r = run(
        sandboxed(
            &["--ready-file", ready.to_str().unwrap()],
            &["sh", "-c", CHECK_IFACE],
        ),
        Duration::from_secs(30),
    );
    ready_line_then_interface_up(&r, &ready);
    println!("{}", r.stdout.lines().next().unwrap());
}

#[test]
#[ignore = "needs setpriv (and root to become nobody)"]
fn the_sandbox_works_for_nobody() {
    let dir = tmp("nobody");
    let bin = for_nobody(Path::new(ecsync()), &dir);
    let bin = bin.to_str().unwrap();
    let serve = |extra: &[&str], command: &[&str]| {
        let mut c = as_nobody(bin, &dir);
        c.args(["serve", "--preset", "paper-2024", "--quiet", "--sandbox"])
            .args(extra)
            .arg("--")
            .args(command);
        c
    };
    let r = run(serve(&[], &["sh", "-c", "exit 3"]), Duration::from_secs(30));
    assert_eq!(code(&r), Some(3), "{}", r.stderr);
    assert!(
        r.stderr.contains("in a user namespace (unprivileged)"),
        "{}",
        r.stderr
    );
    let ready = dir.join("ready.json");
    let r = run(
        serve(
            &["--ready-file", ready.to_str().unwrap()],
            &["sh", "-c", CHECK_IFACE],
        ),
        Duration::from_secs(30),
    );
    ready_line_then_interface_up(&r, &ready);
    // Refused real-time settings are one line each, and serve goes on.
    for l in r.stderr.lines().filter(|l| l.contains("warning")) {
        assert!(l.starts_with("ecsync serve: warning: "), "{l}");
    }
    println!("as nobody: {}", r.stderr);
}

#[test]
#[ignore = "needs setpriv (and root to become nobody), pysoem"]
fn pysoem_runs_a_master_s_ci_test_in_the_sandbox_as_nobody() {
    let _one = TIMED.lock().unwrap_or_else(|e| e.into_inner());
    let dir = tmp("pysoem-nobody");
    let py = python(|py| as_nobody(py, &dir));
    let bin = for_nobody(Path::new(ecsync()), &dir);
    let cycle = for_nobody(&script("soem_cycle.py"), &dir);
    let mut c = as_nobody(bin.to_str().unwrap(), &dir);
    c.args([
        "serve",
        "--preset",
        "paper-2024",
        "--quiet",
        "--sandbox",
        "--",
    ])
    .arg(&py)
    .arg(&cycle);
    let r = run(c, Duration::from_secs(240));
    println!("{}{}({:.1} s)", r.stdout, r.stderr, r.took.as_secs_f64());
    assert_master_passed(&r);
    let summary = r.stdout.lines().nth(1).unwrap_or_default();
    let wkc_errors = timeouts_from_serve_s_stalls(&r);
    assert!(
        summary.starts_with(
            "soem_cycle: 5000 cycles of 4000 us in OP on master0 (6 slaves, 6 with SYNC0"
        ) && summary.contains(&format!(
            " {wkc_errors} working counter errors (expected 18)"
        )),
        "{summary}"
    );
}

#[test]
#[ignore = "needs network namespaces (root or unprivileged user namespaces), pysoem"]
fn twenty_back_to_back_pysoem_sessions_against_one_serve() {
    let _one = TIMED.lock().unwrap_or_else(|e| e.into_inner());
    let py = python(|py| Command::new(py));
    let mut c = sandboxed(&[], &[py.as_str()]);
    c.arg(script("sessions.py")).arg("20");
    let r = run(c, Duration::from_secs(120));
    println!("{}({:.1} s)", r.stdout, r.took.as_secs_f64());
    assert_eq!(code(&r), Some(0), "{}{}", r.stdout, r.stderr);
    assert!(r.stdout.contains("sessions: 20 of 20 ok"), "{}", r.stdout);
}

/// `ecsync serve --preset akd` (issue 32, acceptance 5): two drives whose firmware takes AL
/// control 4.5 ms after a write and refuses another write until then (working counter 0), as
/// the Kollmorgen AKD does, answers the mailbox after 1.2 ms and reads the SII 4 bytes at a
/// time. SOEM (through pysoem), which writes AL control twice at its start and polls the
/// states, reaches OP and exchanges process data with every working counter as expected.
#[test]
#[ignore = "needs network namespaces (root or unprivileged user namespaces), pysoem"]
fn pysoem_reaches_op_on_the_akd_preset() {
    let _one = TIMED.lock().unwrap_or_else(|e| e.into_inner());
    let py = python(|py| Command::new(py));
    let mut c = Command::new(ecsync());
    c.args(["serve", "--preset", "akd", "--quiet", "--sandbox", "--"])
        .arg(&py)
        .arg(script("soem_cycle.py"))
        // The AKD's 32-bit DC time wraps every 2^32 ns, not a whole number of 4 ms cycles:
        // the phase SOEM's loop reads jumps by 967 us there, and when a wrap fell within the
        // 200 cycles it holds before requesting OP, the script gave up (a third of the runs).
        // What is tested here is the AL handshake and OP, so the phase is not waited for.
        .args(["--slaves", "2", "--cycles", "1000", "--settle-us", "2000"]);
    let r = run(c, Duration::from_secs(120));
    println!("{}{}({:.1} s)", r.stdout, r.stderr, r.took.as_secs_f64());
    assert_master_passed(&r);
    let summary = r.stdout.lines().find(|l| l.starts_with("soem_cycle:"));
    let summary = summary.unwrap_or_default();
    let wkc_errors = timeouts_from_serve_s_stalls(&r);
    assert!(
        summary.starts_with("soem_cycle: 1000 cycles of 4000 us in OP on ")
            && summary.contains("(2 slaves, 2 with SYNC0")
            && summary.contains(&format!(" {wkc_errors} working counter errors")),
        "{summary}"
    );
}

/// The ethercrab example `ci_master`.
fn ethercrab_example() -> PathBuf {
    ethercrab_example_named("ci_master")
}

/// An ethercrab example, built as CI builds it (`cargo test` builds every example; this
/// builds it again, a no-op then, so that the test also runs alone).
fn ethercrab_example_named(name: &str) -> PathBuf {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let mut c = Command::new(cargo);
    c.args(["build", "-q", "-p", "ecsync-ethercrab", "--example", name])
        .arg("--message-format=json");
    if !cfg!(debug_assertions) {
        c.arg("--release");
    }
    let o = c.current_dir(env!("CARGO_MANIFEST_DIR")).output().unwrap();
    assert!(
        o.status.success(),
        "building the ethercrab example: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    String::from_utf8_lossy(&o.stdout)
        .lines()
        .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
        .filter(|v| v["target"]["name"] == name)
        .find_map(|v| v["executable"].as_str().map(PathBuf::from))
        .expect("cargo names the example's executable")
}

#[test]
#[ignore = "needs setpriv (and root to become nobody)"]
fn the_ethercrab_example_runs_in_the_sandbox_as_nobody() {
    let _one = TIMED.lock().unwrap_or_else(|e| e.into_inner());
    let dir = tmp("ethercrab-nobody");
    let example = for_nobody(&ethercrab_example(), &dir);
    let bin = for_nobody(Path::new(ecsync()), &dir);
    let mut c = as_nobody(bin.to_str().unwrap(), &dir);
    c.args([
        "serve",
        "--preset",
        "paper-2024",
        "--quiet",
        "--sandbox",
        "--",
    ])
    .arg(&example);
    let r = run(c, Duration::from_secs(120));
    println!("{}{}({:.1} s)", r.stdout, r.stderr, r.took.as_secs_f64());
    assert_eq!(code(&r), Some(0), "{}", r.stderr);
    let summary = r.stdout.lines().nth(1).unwrap_or_default();
    assert!(
        summary.starts_with("ci_master: 5000 cycles of 4000 us in OP on master0")
            && summary.contains(" 0 working counter errors (expected 18)"),
        "{summary}"
    );
}

/// The master's own count of its frames that reached the reference after the SYNC0 they were
/// for (its deadline in DC time against the reference's time of the frame): the independent
/// figure the judge's `late` is checked against.
fn own_past_sync0(summary: &str) -> u64 {
    let end = summary
        .find(" frames past their SYNC0")
        .unwrap_or_else(|| panic!("no count of frames past SYNC0 in {summary:?}"));
    summary[..end]
        .rsplit(' ')
        .next()
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("{summary:?}"))
}

/// The judge's summary.json in `dir`.
fn judged(dir: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(dir.join("summary.json")).expect("the judge's summary");
    serde_json::from_str(&text).unwrap()
}

/// `master args...` (a path nobody can run) under `serve --sandbox --expect late=0 --out` as
/// nobody: the run, its master's summary line and the judge's figures.
fn judged_run(dir: &Path, master: &[&str], args: &[&str]) -> (Ran, String, serde_json::Value) {
    let bin = for_nobody(Path::new(ecsync()), dir);
    let out = dir.join("judge");
    std::fs::create_dir_all(&out).unwrap();
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(&out, std::fs::Permissions::from_mode(0o777)).unwrap();
    let mut c = as_nobody(bin.to_str().unwrap(), dir);
    c.args(["serve", "--preset", "paper-2024", "--quiet", "--out"])
        .arg(&out)
        .args(["--expect", "late=0", "--sandbox", "--"])
        .args(master)
        .args(args);
    let r = run(c, Duration::from_secs(240));
    println!("{}{}({:.1} s)", r.stdout, r.stderr, r.took.as_secs_f64());
    let summary = r.stdout.lines().nth(1).unwrap_or_default().to_string();
    (r, summary, judged(&out))
}

/// What `--expect late=0` must make of a run: exit 0 when the judge found no frame after its
/// SYNC0, else 1 naming the threshold. In step, a master that counted none of its own frames
/// past SYNC0 (by its deadline and the reference's time of each frame) gets none from the
/// judge; jittered (`sleeps` sleeps of 3 ms in a 4 ms cycle whose frames come 2 ms before
/// SYNC0), every sleep costs a pulse without new outputs and the judge finds late frames. (The
/// counts are not compared one for one: a master that skips the cycle it slept through has
/// missed a pulse without a late frame, and the master's own count is its estimate.)
fn check_expect_late(r: &Ran, summary: &str, judge: &serde_json::Value, sleeps: u64) {
    let own = own_past_sync0(summary);
    let late = judge["late"].as_u64().unwrap();
    let missed = judge["missed"].as_u64().unwrap();
    if sleeps == 0 {
        // In step the judge's late frames are the host's stalls the master saw itself: never
        // more than its own count but at the edge (a frame whose first bit reached the
        // reference before the pulse and whose last bit passed the drives after it is late for
        // the judge, not for the master's count). Fewer is the master's estimate erring (its
        // DC time of a frame is reckoned from the last cycle that woke on time: CI saw 1
        // against its 4 after a 3 ms stall).
        assert!(
            late <= own + 1,
            "in step: the judge's {late} late frames against the master's own {own}: {summary}"
        );
    }
    if sleeps > 0 {
        assert!(
            missed >= sleeps && late > 0 && own > 0,
            "{sleeps} sleeps past SYNC0: the judge found {late} late frames, {missed} missed pulses; the master {own}: {summary}"
        );
    }
    if late == 0 {
        assert_master_passed(r);
        assert!(
            r.stderr.contains("every --expect threshold holds"),
            "{}",
            r.stderr
        );
    } else {
        assert_eq!(code(r), Some(1), "{}", r.stderr);
        assert!(
            r.stderr.contains(&format!(
                "judge: --expect broken: late = {late}, expected 0"
            )),
            "{}",
            r.stderr
        );
    }
}

#[test]
#[ignore = "needs setpriv (and root to become nobody), pysoem"]
fn expect_late_0_passes_pysoem_in_step_and_fails_it_jittered_past_sync0() {
    let _one = TIMED.lock().unwrap_or_else(|e| e.into_inner());
    let dir = tmp("pysoem-expect");
    let py = python(|py| as_nobody(py, &dir));
    let cycle = for_nobody(&script("soem_cycle.py"), &dir);
    let master = [py.as_str(), cycle.to_str().unwrap()];
    let (r, summary, judge) = judged_run(&dir, &master, &["--cycles", "3000"]);
    check_expect_late(&r, &summary, &judge, 0);
    // A 3 ms sleep every 500 cycles of 4 ms (six in 3000): those frames reach the drives past
    // the SYNC0 (2 ms after their usual instant) they were for.
    let jitter = [
        "--cycles",
        "3000",
        "--jitter-every",
        "500",
        "--jitter-us",
        "3000",
    ];
    let (r, summary, judge) = judged_run(&dir, &master, &jitter);
    check_expect_late(&r, &summary, &judge, 6);
}

#[test]
#[ignore = "needs setpriv (and root to become nobody)"]
fn expect_late_0_passes_the_ethercrab_example_in_step_and_fails_it_jittered() {
    let _one = TIMED.lock().unwrap_or_else(|e| e.into_inner());
    let dir = tmp("ethercrab-expect");
    let example = for_nobody(&ethercrab_example(), &dir);
    let master = [example.to_str().unwrap()];
    let (r, summary, judge) = judged_run(&dir, &master, &["--cycles", "3000"]);
    check_expect_late(&r, &summary, &judge, 0);
    let jitter = [
        "--cycles",
        "3000",
        "--jitter-every",
        "500",
        "--jitter-us",
        "3000",
    ];
    let (r, summary, judge) = judged_run(&dir, &master, &jitter);
    check_expect_late(&r, &summary, &judge, 6);
}

/// Two masters' frames on one segment, from a raw socket of Python's standard library: a BRD
/// from one source address, then from another; and from one address, two index streams
/// interleaved (two master processes on one interface).
const TWO_MASTERS_PY: &str = r#"
import os, socket, struct, sys, time
s = socket.socket(socket.AF_PACKET, socket.SOCK_RAW)
s.bind((os.environ["ECSYNC_IFACE"], 0))
def brd(src, index):
    dg = struct.pack("<BBHHHH", 7, index, 0, 0x0000, 1, 0) + b"\0" + b"\0\0"
    return b"\xff" * 6 + src + b"\x88\xa4" + struct.pack("<H", len(dg) | 0x1000) + dg + b"\0" * 40
a, b = bytes.fromhex("001b21000001"), bytes.fromhex(sys.argv[1])
frames = [brd(a, 1), brd(b, 2)] if sys.argv[2] == "address" else [
    brd(a, (i // 2 if i % 2 == 0 else 100 + i // 2) % 256) for i in range(600)]
for f in frames:
    s.send(f)
    time.sleep(0.001)
time.sleep(0.2)
"#;

#[test]
#[ignore = "needs network namespaces (root or unprivileged user namespaces)"]
fn a_second_master_on_the_segment_is_warned_about() {
    let r = run(
        sandboxed(
            &[],
            &["python3", "-c", TWO_MASTERS_PY, "001b21000002", "address"],
        ),
        Duration::from_secs(30),
    );
    assert_eq!(code(&r), Some(0), "{}", r.stderr);
    assert_eq!(
        r.stderr
            .matches("warning: a second master on the segment")
            .count(),
        1,
        "{}",
        r.stderr
    );
    assert!(
        r.stderr
            .contains("frames from 00:1b:21:00:00:02 besides 00:1b:21:00:00:01")
    );
    // One address, two index streams.
    let r = run(
        sandboxed(
            &[],
            &["python3", "-c", TWO_MASTERS_PY, "001b21000001", "streams"],
        ),
        Duration::from_secs(30),
    );
    assert_eq!(code(&r), Some(0), "{}", r.stderr);
    assert!(
        r.stderr.contains("the datagram index stepped back"),
        "{}",
        r.stderr
    );
    // One master alone: no warning.
    let r = run(
        sandboxed(
            &[],
            &["python3", "-c", TWO_MASTERS_PY, "001b21000001", "address"],
        ),
        Duration::from_secs(30),
    );
    assert!(!r.stderr.contains("second master"), "{}", r.stderr);
}

/// `ecsync run` (ecsync's own master, the median method) against the sandboxed serve: the
/// judge's phase against SYNC0 is where `compare` puts the same method on the same preset in
/// virtual time (its phase against the grid point, less the 300 us SYNC0 shift), within this
/// host's noise (three of the larger std), and its spread is of the same order. (In virtual
/// time the two agree to the nanosecond: crates/lab/tests/judge_compare.rs.)
#[test]
#[ignore = "needs network namespaces (root or unprivileged user namespaces)"]
fn the_judge_sees_ecsync_run_where_compare_puts_the_same_method() {
    let _one = TIMED.lock().unwrap_or_else(|e| e.into_inner());
    let dir = tmp("judge-vs-compare");
    let judged_dir = dir.join("judge");
    let mut c = sandboxed(
        &["--out", judged_dir.to_str().unwrap()],
        &[
            "sh",
            "-c",
            &format!(
                "{} run --iface \"$ECSYNC_IFACE\" --method median --duration 6 > /dev/null",
                ecsync()
            ),
        ],
    );
    c.current_dir(&dir);
    let r = run(c, Duration::from_secs(120));
    assert_eq!(code(&r), Some(0), "{}", r.stderr);
    let j = judged(&judged_dir);
    let cmp_dir = dir.join("compare");
    let o = Command::new(ecsync())
        .args([
            "compare",
            "--methods",
            "median",
            "--runs",
            "1",
            "--cycles",
            "6000",
            "--quiet",
        ])
        .arg("--out")
        .arg(&cmp_dir)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let c: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(cmp_dir.join("summary.json")).unwrap())
            .unwrap();
    let shift_ns = c["sync0_shift_pct"].as_f64().unwrap() / 100.0 * c["cycle_ns"].as_f64().unwrap();
    let g = &c["methods"]["median"]["ground_truth"]["phase"];
    let (c_mean, c_std) = (
        g["mean"].as_f64().unwrap() - shift_ns,
        g["std"].as_f64().unwrap(),
    );
    let (j_mean, j_std) = (
        j["phase"]["mean_ns"].as_f64().unwrap(),
        j["phase"]["std_ns"].as_f64().unwrap(),
    );
    println!(
        "phase against SYNC0, ns: judge {j_mean:.0} (std {j_std:.0}), compare {c_mean:.0} (std {c_std:.0})"
    );
    assert_eq!(j["cycle_ns"], 1_000_000);
    assert!(
        (j_mean - c_mean).abs() <= 3.0 * j_std.max(c_std),
        "judge {j_mean} (std {j_std}) against compare {c_mean} (std {c_std})"
    );
    assert!(
        j_std < 3.0 * c_std + 20_000.0 && c_std < 3.0 * j_std,
        "{j_std} vs {c_std}"
    );
    assert!(j["pd_frames"].as_u64().unwrap() > 5000, "{j}");
}

/// `serve --preset oversampling --sandbox --out DIR -- command...` (as the current user): the
/// run and the judge's figures of the oversampling terminal (position 1) and the drive (2).
fn judged_oversampling(dir: &Path, command: &[&str]) -> (Ran, serde_json::Value) {
    let out = dir.join("judge");
    let mut c = Command::new(ecsync());
    c.args([
        "serve",
        "--preset",
        "oversampling",
        "--quiet",
        "--sandbox",
        "--out",
    ])
    .arg(&out)
    .arg("--")
    .args(command);
    let r = run(c, Duration::from_secs(180));
    println!("{}{}({:.1} s)", r.stdout, r.stderr, r.took.as_secs_f64());
    assert_eq!(code(&r), Some(0), "{}", r.stderr);
    (r, judged(&out))
}

/// Issue 34, acceptance 1, on a real socket: the `oversampling` preset (a four-sample
/// terminal, SYNC0 250 us, SYNC1 every 1 ms) served to ethercrab 0.7 set up as its users do
/// (ethercrab #368) and cycled as its documentation says: `tx_rx_dc`'s `next_cycle_wait`
/// steps by the SYNC0 period (ethercrab #369), so the loop runs every 250 us and the judge
/// counts three blocks in four overwritten before a SYNC1 event took them, and says so in
/// its verdict. ecsync's own master (`run --oversample 1:4`) on the same serve sends one
/// block a cycle before SYNC1: overwritten and missed only as this host's stalls make them
/// (the drive on SYNC0 beside it counts the same, within 2), under 5 % of the frames (0.2 %
/// on this machine idle; 0 in virtual time: crates/sim/tests/oversampling.rs).
#[test]
#[ignore = "needs network namespaces (root or unprivileged user namespaces)"]
fn ethercrab_tx_rx_dc_steps_by_sync0_on_an_oversampling_terminal_and_ecsync_does_not() {
    let _one = TIMED.lock().unwrap_or_else(|e| e.into_inner());
    let dir = tmp("oversampling");
    let example = ethercrab_example_named("oversampling_master");
    let (r, j) = judged_oversampling(&dir.join("ethercrab"), &[example.to_str().unwrap()]);
    let mean_us: f64 = r
        .stdout
        .split("mean period ")
        .nth(1)
        .and_then(|t| t.split(' ').next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no mean period in {}", r.stdout));
    let t = &j["drives"][1];
    assert_eq!(t["on_sync1"], true, "{t}");
    assert_eq!(t["sync0_cycle_ns"], 1_000_000, "{t}");
    let (frames, over) = (
        t["frames"].as_u64().unwrap(),
        t["overwritten"].as_u64().unwrap_or(0),
    );
    println!("ethercrab: loop every {mean_us} us; terminal {over} of {frames} blocks overwritten");
    assert!(
        mean_us < 500.0,
        "ethercrab's loop at the SYNC0 rate: {mean_us} us"
    );
    assert!(
        over * 2 > frames,
        "most blocks overwritten: {over} of {frames}"
    );
    let verdict = std::fs::read_to_string(dir.join("ethercrab/judge/report.html")).unwrap();
    assert!(
        verdict.contains("blocks of samples were overwritten"),
        "verdict"
    );

    let run_ecsync = format!(
        "{} run --iface \"$ECSYNC_IFACE\" --method median --oversample 1:4 --duration 4 > /dev/null",
        ecsync()
    );
    let (_, j) = judged_oversampling(&dir.join("ecsync"), &["sh", "-c", &run_ecsync]);
    let (t, d) = (&j["drives"][1], &j["drives"][2]);
    assert_eq!(t["on_sync1"], true, "{t}");
    assert_eq!(t["al_state"], "Op", "{t}");
    let frames = t["frames"].as_u64().unwrap();
    let over = t["overwritten"].as_u64().unwrap_or(0);
    let missed = t["missed"].as_u64().unwrap();
    println!(
        "ecsync: terminal {over} overwritten, {missed} missed of {frames}; drive {} overwritten, {} missed",
        d["overwritten"].as_u64().unwrap_or(0),
        d["missed"]
    );
    assert!(frames >= 3_500, "{frames} frames in 4 s");
    // The terminal on SYNC1 fares as the drive on SYNC0 on the same grid (the host's stalls
    // are the only cause), and both keep nearly every event.
    let d_over = d["overwritten"].as_u64().unwrap_or(0);
    let d_missed = d["missed"].as_u64().unwrap();
    assert!(
        over.abs_diff(d_over) <= 2 && missed.abs_diff(d_missed) <= 2,
        "{t}\n{d}"
    );
    assert!(over * 20 <= frames && missed * 20 <= frames, "{t}");
}

/// Cable redundancy with no root: `serve --sandbox --ring-iface` makes a second veth pair (the
/// ring's far end and COMMAND's second port, `ECSYNC_RING_IFACE`), and ecsync's `run
/// --ring-iface` as nobody keeps the twelve drives of a ring through a cable pulled between
/// drives 5 and 6 for 2 s (`common/ring.rs` says what is checked).
#[test]
#[ignore = "needs setpriv (and root to become nobody)"]
fn a_redundant_master_keeps_a_ring_through_a_pulled_cable_in_the_sandbox_as_nobody() {
    let _one = TIMED.lock().unwrap_or_else(|e| e.into_inner());
    let dir = tmp("ring-nobody");
    let bin = for_nobody(Path::new(ecsync()), &dir);
    let bin = bin.to_str().unwrap();
    std::fs::write(dir.join("ring.toml"), ring::ring_toml()).unwrap();
    std::fs::write(dir.join("pull.toml"), ring::PULL_5_6).unwrap();
    let master = format!(
        "{bin} run --iface $ECSYNC_IFACE --ring-iface $ECSYNC_RING_IFACE --duration 8 --timeout-us 100000 --json > run.json"
    );
    let mut c = as_nobody(bin, &dir);
    c.args(["serve", "--config", "ring.toml", "--faults", "pull.toml"])
        .args([
            "--quiet",
            "--out",
            "judge",
            "--sandbox",
            "--ring-iface",
            "ecsync1",
        ])
        .args(["--", "sh", "-c", &master]);
    let r = run(c, Duration::from_secs(120));
    assert_eq!(code(&r), Some(0), "{}", r.stderr);
    let ready: serde_json::Value =
        serde_json::from_str(r.stdout.lines().next().unwrap_or_default()).unwrap();
    assert_eq!(ready["master_ring_iface"], "master1", "{ready}");
    assert!(!r.stderr.contains("a second master"), "{}", r.stderr);
    let read = |p: &str| -> serde_json::Value {
        serde_json::from_str(&std::fs::read_to_string(dir.join(p)).unwrap()).unwrap()
    };
    ring::check_ring_through_the_pull(&read("run.json"), &read("judge/summary.json"));
}
