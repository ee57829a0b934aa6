//! `ecsync serve --sandbox -- COMMAND`: the segment served in a private network (a network
//! namespace, inside a user namespace of its own when the caller is not privileged: no root
//! needed) on one end of a veth pair, COMMAND run on the other end with `ECSYNC_IFACE` naming
//! it; serving stops when COMMAND exits, and serve exits with its code. With `--ring-iface` a
//! second pair: the served ring's far end and the master's second port (`ECSYNC_RING_IFACE`).
//! And the readiness
//! handshake of every `serve`: one JSON line on stdout once the segment is serving (and the
//! same in `--ready-file`).

use super::STOP;
use crate::source::SourceArgs;
use anyhow::{Context, Result, anyhow};
use ecsync_net::sys::sandbox as sys;
use std::io::Write;
use std::os::unix::process::ExitStatusExt;
use std::path::PathBuf;
use std::process::{Child, Command, ExitCode, ExitStatus};
use std::sync::Mutex;
use std::sync::atomic::Ordering;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// The served end of the veth pair, unless `--iface` names it.
const SERVED_IFACE: &str = "ecsync0";
/// The end COMMAND gets (`ECSYNC_IFACE`).
const MASTER_IFACE: &str = "master0";
/// With a ring (`--ring-iface`), the second pair's end COMMAND gets (`ECSYNC_RING_IFACE`).
const MASTER_RING_IFACE: &str = "master1";
/// How long a COMMAND still running when serving stops has, after the signal, before its
/// process group is killed: serve exits within a second of being told to.
const KILL_AFTER: Duration = Duration::from_millis(500);

/// The options of `serve` for the sandbox and the readiness handshake.
#[derive(Debug, Clone, Default, clap::Args)]
pub struct SandboxArgs {
    /// Serve in a private network of its own (a network namespace, in a user namespace when not
    /// root: no privileges needed) on one end of a veth pair (--iface names it, default
    /// ecsync0), run COMMAND (after `--`) on the other end (master0) with its name in
    /// ECSYNC_IFACE, stop when COMMAND exits and exit with its code (128+N for signal N).
    /// COMMAND runs in a process group of its own: a SIGINT/SIGTERM/SIGHUP to serve is
    /// forwarded to that group, which is killed if it still runs half a second later; what
    /// COMMAND leaves running is killed when it exits. When stdin is the terminal serve runs
    /// in the foreground of, that group gets the terminal while COMMAND runs (an interactive
    /// COMMAND reads it; Ctrl-C reaches COMMAND), and serve takes it back when COMMAND ends.
    #[arg(long, requires = "command")]
    pub sandbox: bool,
    /// Also write the ready line (the JSON object printed on stdout once the segment is
    /// serving) to this file, atomically (a temporary file renamed).
    #[arg(long, value_name = "PATH")]
    pub ready_file: Option<PathBuf>,
    /// With --sandbox: the master to run, and its arguments.
    #[arg(last = true, requires = "sandbox", value_name = "COMMAND")]
    pub command: Vec<String>,
}

impl SandboxArgs {
    /// With --sandbox, COMMAND (and the option cleared: `serve` runs once inside).
    pub fn take_command(&mut self) -> Option<Vec<String>> {
        if !self.sandbox {
            return None;
        }
        self.sandbox = false;
        Some(std::mem::take(&mut self.command))
    }
}

/// COMMAND waiting for the segment to serve, then running.
enum State {
    Off,
    Pending {
        command: Vec<String>,
        master: String,
        master_ring: Option<String>,
    },
    Running(JoinHandle<ExitStatus>),
    SpawnFailed(u8),
}

static STATE: Mutex<State> = Mutex::new(State::Off);

fn state() -> std::sync::MutexGuard<'static, State> {
    STATE.lock().unwrap_or_else(|e| e.into_inner())
}

/// The ready line: what is served where, as one JSON object.
pub fn ready_json(
    iface: &str,
    master_iface: Option<&str>,
    master_ring_iface: Option<&str>,
    slaves: usize,
    source: &SourceArgs,
) -> String {
    let preset = match (&source.preset, &source.config) {
        (Some(p), None) => Some(p.as_str()),
        (None, None) => Some("paper-2024"),
        _ => None,
    };
    // Written out so that the keys keep this order ("event" first), as a reader scanning
    // stdout expects; every value goes through serde_json.
    let j = |v: serde_json::Value| v.to_string();
    // A ring's second master port only where there is one: the line is as before otherwise.
    let ring = master_ring_iface.map_or(String::new(), |r| {
        format!(",\"master_ring_iface\":{}", j(r.into()))
    });
    format!(
        "{{\"event\":\"ready\",\"iface\":{},\"master_iface\":{}{ring},\"slaves\":{slaves},\"pid\":{},\"preset\":{},\"config\":{}}}",
        j(iface.into()),
        j(master_iface.into()),
        std::process::id(),
        j(preset.into()),
        j(source
            .config
            .as_ref()
            .map(|p| p.display().to_string())
            .into()),
    )
}

/// Called by `serve` when the socket is open and the loop about to start: prints the ready
/// line on stdout (and writes `--ready-file`), then, in the sandbox, starts COMMAND.
pub fn ready(args: &SandboxArgs, iface: &str, slaves: usize, source: &SourceArgs) -> Result<()> {
    let mut st = state();
    let (master, master_ring) = match &*st {
        State::Pending {
            master,
            master_ring,
            ..
        } => (Some(master.clone()), master_ring.clone()),
        _ => (None, None),
    };
    let line = ready_json(
        iface,
        master.as_deref(),
        master_ring.as_deref(),
        slaves,
        source,
    );
    if let Some(p) = &args.ready_file {
        ecsync_lab::output::write_atomic(p, format!("{line}\n").as_bytes())
            .with_context(|| format!("writing the ready file {}", p.display()))?;
    }
    let mut out = std::io::stdout().lock();
    if let Err(e) = writeln!(out, "{line}").and_then(|()| out.flush()) {
        // A closed stdout is no reason not to serve.
        eprintln!("ecsync serve: warning: the ready line could not be printed: {e}");
    }
    drop(out);
    if let State::Pending {
        command,
        master,
        master_ring,
    } = std::mem::replace(&mut *st, State::Off)
    {
        sys::catch_termination_signals(&STOP).context("catching SIGINT/SIGTERM")?;
        let mut cmd = Command::new(&command[0]);
        cmd.args(&command[1..]).env("ECSYNC_IFACE", &master);
        if let Some(r) = &master_ring {
            cmd.env("ECSYNC_RING_IFACE", r);
        }
        // An interactive COMMAND reads the terminal serve was started from: its group gets
        // it (a read from the background would stop it with SIGTTIN), serve takes it back
        // when COMMAND ends.
        let loan = if sys::owns_foreground_terminal() {
            sys::TerminalLoan::begin()
                .map_err(|e| {
                    eprintln!(
                        "ecsync serve: warning: the terminal stays serve's, COMMAND cannot read it (ignoring SIGTTOU: {e})"
                    );
                })
                .ok()
        } else {
            None
        };
        sys::plain_child(&mut cmd, loan.as_ref());
        match cmd.spawn() {
            Ok(child) => *st = State::Running(std::thread::spawn(move || watch(child, loan))),
            Err(e) => {
                // The child may have taken the terminal before its exec failed.
                drop(loan);
                let code = if e.kind() == std::io::ErrorKind::NotFound {
                    127
                } else {
                    126
                };
                *st = State::SpawnFailed(code);
                return Err(anyhow!("cannot run {}: {e}", command[0]));
            }
        }
    }
    Ok(())
}

/// Waits for COMMAND: raises the stop flag when it exits, kills what it left running in its
/// process group and takes the terminal back (`terminal`, if it was lent); forwards a stop to
/// the group (the signal serve was sent, or SIGTERM when serving ended otherwise), and kills
/// the group if COMMAND outlives that by [`KILL_AFTER`].
fn watch(mut child: Child, terminal: Option<sys::TerminalLoan>) -> ExitStatus {
    // COMMAND leads its group (`plain_child`).
    let group = child.id();
    let mut stopping: Option<Instant> = None;
    loop {
        match child.try_wait() {
            Ok(Some(status)) => {
                STOP.store(true, Ordering::Relaxed);
                // A shell's children would hold the private network, and outlive serve.
                let _ = sys::signal_group(group, libc::SIGKILL);
                drop(terminal);
                return status;
            }
            Ok(None) => {}
            Err(e) => {
                eprintln!("ecsync serve: waiting for COMMAND: {e}");
                STOP.store(true, Ordering::Relaxed);
                let _ = child.kill();
                return child.wait().unwrap_or(ExitStatus::from_raw(1 << 8));
            }
        }
        let now = Instant::now();
        match stopping {
            None if STOP.load(Ordering::Relaxed) => {
                // A signal to serve alone (a `kill`, or a Ctrl-C when the terminal was not
                // COMMAND's to read: stdin not serve's terminal) is passed on.
                let sig = sys::stop_signal().map_or(libc::SIGTERM, |(sig, _)| sig);
                let _ = sys::signal_group(group, sig);
                stopping = Some(now);
            }
            Some(t) if now - t >= KILL_AFTER => {
                eprintln!(
                    "ecsync serve: COMMAND still runs {} ms after it was told to stop: killed with its process group",
                    KILL_AFTER.as_millis()
                );
                let _ = sys::signal_group(group, libc::SIGKILL);
                stopping = Some(now + Duration::from_secs(3600));
            }
            _ => {}
        }
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// `serve --sandbox`: enters the private network (with `ring`, the served ring end's name, a
/// second pair), runs `serve` on its end (which starts COMMAND through [`ready`]), and returns
/// COMMAND's exit code (or serve's when COMMAND succeeded and serve did not).
pub fn run(
    command: Vec<String>,
    iface: &str,
    ring: Option<&str>,
    serve: impl FnOnce(String) -> Result<ExitCode>,
) -> Result<ExitCode> {
    let served = if iface.is_empty() {
        SERVED_IFACE
    } else {
        iface
    };
    if served == MASTER_IFACE {
        anyhow::bail!("--iface {served}: that is the name of COMMAND's end; choose another");
    }
    if let Some(r) = ring
        && [served, MASTER_IFACE, MASTER_RING_IFACE].contains(&r)
    {
        anyhow::bail!(
            "--ring-iface {r}: that name is taken by another end in the sandbox; choose another (e.g. ecsync1)"
        );
    }
    let mut pairs = vec![(served, MASTER_IFACE)];
    pairs.extend(ring.map(|r| (r, MASTER_RING_IFACE)));
    let sb = sys::enter(&pairs).map_err(|e| anyhow!("--sandbox: {e}"))?;
    eprintln!(
        "ecsync serve: sandbox: a private network namespace{}, {served} served, COMMAND on {MASTER_IFACE} (ECSYNC_IFACE){}",
        if sb.user_namespace {
            " in a user namespace (unprivileged)"
        } else {
            ""
        },
        ring.map_or(String::new(), |r| format!(
            "; the ring's far end {r}, COMMAND's second port {MASTER_RING_IFACE} (ECSYNC_RING_IFACE)"
        ))
    );
    if let Some(w) = &sb.sysfs_warning {
        eprintln!("ecsync serve: warning: {w}");
    }
    *state() = State::Pending {
        command,
        master: MASTER_IFACE.to_string(),
        master_ring: ring.map(|_| MASTER_RING_IFACE.to_string()),
    };
    let served = serve(served.to_string());
    STOP.store(true, Ordering::Relaxed);
    let st = std::mem::replace(&mut *state(), State::Off);
    let status = match st {
        State::Running(h) => h
            .join()
            .map_err(|_| anyhow!("COMMAND's watcher panicked"))?,
        State::SpawnFailed(code) => {
            eprintln!("ecsync: error: {:#}", served.err().unwrap_or(anyhow!("?")));
            return Ok(ExitCode::from(code));
        }
        State::Off | State::Pending { .. } => return served,
    };
    let code = match (status.code(), status.signal()) {
        (Some(c), _) => c as u8,
        (None, Some(s)) => (128 + s) as u8,
        (None, None) => 1,
    };
    eprintln!("ecsync serve: COMMAND exited: {status}; exit code {code}");
    let served = served?;
    Ok(if code == 0 {
        served
    } else {
        ExitCode::from(code)
    })
}
