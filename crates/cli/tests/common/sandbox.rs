//! What the sandbox tests share: the binary, fresh folders, `serve --sandbox` and waiting
//! for a child with a limit.
#![allow(dead_code)] // each test binary uses its own part

use std::io::Read;
use std::path::PathBuf;
use std::process::{Child, Command, ExitStatus};
use std::time::{Duration, Instant};

pub const NEEDS_NS: &str = "needs network namespaces (root or unprivileged user namespaces)";

pub fn ecsync() -> &'static str {
    env!("CARGO_BIN_EXE_ecsync")
}

/// A fresh directory any user can read and enter.
pub fn tmp(name: &str) -> PathBuf {
    use std::os::unix::fs::PermissionsExt;
    let dir = std::env::temp_dir().join(format!("ecsync-sandbox-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::set_permissions(&dir, std::fs::Permissions::from_mode(0o777)).unwrap();
    dir
}

pub fn drain(r: Option<impl Read + Send + 'static>) -> std::thread::JoinHandle<String> {
    std::thread::spawn(move || {
        let mut s = String::new();
        if let Some(mut r) = r {
            let _ = r.read_to_string(&mut s);
        }
        s
    })
}

pub fn wait_at_most(child: &mut Child, limit: Duration) -> ExitStatus {
    let t0 = Instant::now();
    loop {
        if let Some(s) = child.try_wait().unwrap() {
            return s;
        }
        if t0.elapsed() > limit {
            let _ = child.kill();
            return child.wait().unwrap();
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// `ecsync serve --quiet --sandbox [extra] -- command...`.
pub fn sandboxed(extra: &[&str], command: &[&str]) -> Command {
    let mut c = Command::new(ecsync());
    c.args(["serve", "--preset", "paper-2024", "--quiet", "--sandbox"])
        .args(extra)
        .arg("--")
        .args(command);
    c
}
