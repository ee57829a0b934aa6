//! `serve --control PATH`: a local control socket (Unix stream, one JSON object a line each
//! way) to inject a fault now or at a time, clear it, start the schedule's clock (its epoch)
//! now, read the counters and the judge's figures, reset the segment to power-on, and stop; and
//! `ecsync ctl`, its command-line client.
//!
//! The socket is served by a thread of its own; each request goes to the serving loop through
//! a channel and is answered between two frames (the loop polls every
//! [`POLL_INTERVAL_NS`]), so a command never races the segment.

use anyhow::{Context, Result, bail};
use serde_json::{Value, json};
use std::io::{BufRead, BufReader, Write};
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::{Path, PathBuf};
use std::sync::mpsc;
use std::time::Duration;

/// How often the serving loop takes control requests, ns.
pub const POLL_INTERVAL_NS: u64 = 2_000_000;

/// How long a client waits for the serving loop's answer.
const ANSWER_TIMEOUT: Duration = Duration::from_secs(5);

/// One request from a client, and where its answer goes.
pub struct Request {
    /// The JSON object the client sent.
    pub body: Value,
    /// The answer (one JSON object).
    pub answer: mpsc::Sender<Value>,
}

/// The control socket, bound.
pub struct ControlServer {
    path: PathBuf,
    /// Requests for the serving loop.
    pub requests: mpsc::Receiver<Request>,
}

impl ControlServer {
    /// Binds `path` (a stale socket file left by a serve that died is replaced; one a running
    /// serve answers on is refused) and starts accepting.
    pub fn bind(path: &Path) -> Result<ControlServer> {
        if path.exists() {
            if UnixStream::connect(path).is_ok() {
                bail!(
                    "--control {}: another process serves on this socket; fix: give another path, or stop it",
                    path.display()
                );
            }
            std::fs::remove_file(path).with_context(|| {
                format!(
                    "--control {}: a file is in the way and cannot be removed",
                    path.display()
                )
            })?;
        }
        let listener = UnixListener::bind(path).with_context(|| {
            format!(
                "--control {}: cannot create the socket (does its directory exist and is it writable?)",
                path.display()
            )
        })?;
        let (tx, rx) = mpsc::channel();
        std::thread::Builder::new()
            .name("ecsync-control".into())
            .spawn(move || {
                for conn in listener.incoming().flatten() {
                    let tx = tx.clone();
                    let _ = std::thread::Builder::new()
                        .name("ecsync-control-client".into())
                        .spawn(move || client(conn, tx));
                }
            })
            .context("starting the control socket's thread")?;
        Ok(ControlServer {
            path: path.to_path_buf(),
            requests: rx,
        })
    }
}

impl Drop for ControlServer {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.path);
    }
}

/// Serves one client: a request a line, an answer a line.
fn client(conn: UnixStream, tx: mpsc::Sender<Request>) {
    let Ok(mut out) = conn.try_clone() else {
        return;
    };
    for line in BufReader::new(conn).lines() {
        let Ok(line) = line else { return };
        if line.trim().is_empty() {
            continue;
        }
        let answer = match serde_json::from_str::<Value>(&line) {
            Ok(body) if body.is_object() => {
                let (atx, arx) = mpsc::channel();
                if tx.send(Request { body, answer: atx }).is_err() {
                    return;
                }
                arx.recv_timeout(ANSWER_TIMEOUT).unwrap_or_else(|_| {
                    error("serve did not answer within 5 s (it is stopping, or stalled)")
                })
            }
            Ok(_) => error("a request is one JSON object, e.g. {\"cmd\":\"status\"}"),
            Err(e) => error(&format!("not JSON: {e}")),
        };
        if writeln!(out, "{answer}").is_err() {
            return;
        }
    }
}

/// An answer that says what went wrong.
pub fn error(text: &str) -> Value {
    json!({"ok": false, "error": text})
}

/// The commands, for errors and help.
pub const COMMANDS: &str = "status, judge, inject, clear, epoch, reset, stop";

/// Arguments of `ecsync ctl`.
#[derive(Debug, clap::Args)]
#[command(after_help = CTL_AFTER_HELP)]
pub struct CtlArgs {
    /// The control socket `serve --control` opened.
    #[arg(long)]
    control: PathBuf,
    /// The command: `status`, `judge`, `epoch`, `reset`, `stop`, `clear [FAULT]`, `inject KIND
    /// [key=value ...]` (the keys of a `[[fault]]` entry; `in_s=` or `at_s=` say when), or
    /// one JSON object as is.
    #[arg(required = true, num_args = 1.., allow_hyphen_values = true)]
    command: Vec<String>,
}

const CTL_AFTER_HELP: &str = "Examples:
  ecsync ctl --control /tmp/ecsync.sock status
  ecsync ctl --control /tmp/ecsync.sock inject power_cycle slave=2 for_s=0.5
  ecsync ctl --control /tmp/ecsync.sock inject loss probability=0.1 for_s=2 in_s=1
  ecsync ctl --control /tmp/ecsync.sock clear
  ecsync ctl --control /tmp/ecsync.sock '{\"cmd\":\"judge\"}'
The answer is one JSON line on stdout; the exit code is 1 when it says \"ok\": false.";

/// A value of `key=value`: a number when it reads as one, else a string.
fn value_of(s: &str) -> Value {
    if let Ok(i) = s.parse::<i64>() {
        return json!(i);
    }
    if let Ok(f) = s.parse::<f64>() {
        return json!(f);
    }
    match s {
        "true" => json!(true),
        "false" => json!(false),
        _ => json!(s),
    }
}

/// The request `ecsync ctl`'s words make.
pub fn request_of(words: &[String]) -> Result<Value> {
    let first = words[0].as_str();
    if first.trim_start().starts_with('{') {
        let v: Value = serde_json::from_str(&words.join(" ")).context("the JSON request")?;
        return Ok(v);
    }
    match first {
        "status" | "judge" | "epoch" | "reset" | "stop" if words.len() == 1 => {
            Ok(json!({"cmd": first}))
        }
        "clear" => match words.get(1) {
            None => Ok(json!({"cmd": "clear"})),
            Some(n) => Ok(
                json!({"cmd": "clear", "fault": n.parse::<u64>().with_context(|| format!("clear {n}: the fault's number (from inject's answer or status)"))?}),
            ),
        },
        "inject" => {
            let Some(kind) = words.get(1) else {
                bail!(
                    "inject needs a kind: {}",
                    ecsync_sim::fault::KindName::list()
                );
            };
            let mut fault = serde_json::Map::new();
            fault.insert("kind".into(), json!(kind));
            let mut req = serde_json::Map::new();
            req.insert("cmd".into(), json!("inject"));
            for kv in &words[2..] {
                let Some((k, v)) = kv.split_once('=') else {
                    bail!("inject: {kv:?} is not key=value (e.g. slave=2, for_s=0.5)");
                };
                if k == "in_s" || k == "at_s" {
                    req.insert(k.into(), value_of(v));
                } else {
                    fault.insert(k.into(), value_of(v));
                }
            }
            req.insert("fault".into(), Value::Object(fault));
            Ok(Value::Object(req))
        }
        _ => bail!("unknown command {first:?}: one of {COMMANDS}, or a JSON object"),
    }
}

/// `ecsync ctl`: sends one request, prints the answer.
pub fn ctl(args: CtlArgs) -> Result<std::process::ExitCode> {
    let req = request_of(&args.command)?;
    let mut conn = UnixStream::connect(&args.control).with_context(|| {
        format!(
            "cannot connect to {} (is `ecsync serve --control {}` running?)",
            args.control.display(),
            args.control.display()
        )
    })?;
    conn.set_read_timeout(Some(ANSWER_TIMEOUT + Duration::from_secs(1)))?;
    writeln!(conn, "{req}")?;
    let mut line = String::new();
    BufReader::new(&conn)
        .read_line(&mut line)
        .context("reading serve's answer")?;
    if line.is_empty() {
        bail!("serve closed the connection without an answer");
    }
    print!("{line}");
    let ok = serde_json::from_str::<Value>(&line)
        .ok()
        .and_then(|v| v.get("ok").and_then(Value::as_bool))
        .unwrap_or(false);
    Ok(if ok {
        std::process::ExitCode::SUCCESS
    } else {
        std::process::ExitCode::FAILURE
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn words(s: &str) -> Vec<String> {
        s.split_whitespace().map(String::from).collect()
    }

    #[test]
    fn ctl_words_make_the_requests_the_socket_takes() {
        assert_eq!(
            request_of(&words("status")).unwrap(),
            json!({"cmd":"status"})
        );
        assert_eq!(
            request_of(&words("inject power_cycle slave=2 for_s=0.5 in_s=1")).unwrap(),
            json!({"cmd":"inject","in_s":1,"fault":{"kind":"power_cycle","slave":2,"for_s":0.5}})
        );
        assert_eq!(
            request_of(&words("inject al_error slave=reference")).unwrap(),
            json!({"cmd":"inject","fault":{"kind":"al_error","slave":"reference"}})
        );
        assert_eq!(
            request_of(&words("clear 3")).unwrap(),
            json!({"cmd":"clear","fault":3})
        );
        assert_eq!(
            request_of(&[r#"{"cmd":"judge"}"#.to_string()]).unwrap(),
            json!({"cmd":"judge"})
        );
        let e = request_of(&words("frobnicate")).unwrap_err().to_string();
        assert!(e.contains("status, judge, inject"), "{e}");
        let e = request_of(&words("inject loss 0.1"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("key=value"), "{e}");
    }
}
