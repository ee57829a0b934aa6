//! What the sweep tests share: the binary, a scratch folder, a short comparison per point and
//! a sweep over a grid that must succeed.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

pub fn ecsync() -> Command {
    Command::new(env!("CARGO_BIN_EXE_ecsync"))
}

/// An empty folder of this process for `name`, under `prefix`.
pub fn tmp(prefix: &str, name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("{prefix}-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// A short comparison per point: one run of 2 000 cycles after the 10 s of warm-up the
/// median methods' init frames need, two methods.
pub const SHORT: &[&str] = &[
    "--runs",
    "1",
    "--cycles",
    "2000",
    "--warmup-s",
    "10",
    "--methods",
    "median-fit,soem-pi",
    "--quiet",
];

/// `ecsync sweep` over `grid` into `db`, short points, then `extra`.
pub fn sweep_over(grid: &[&str], db: &Path, extra: &[&str]) -> Command {
    let mut c = ecsync();
    c.arg("sweep")
        .args(grid)
        .args(SHORT)
        .arg("--db")
        .arg(db)
        .args(extra);
    c
}

/// Runs `c`, which must succeed (its output otherwise).
pub fn ok(mut c: Command) -> Output {
    let o = c.output().unwrap();
    assert!(
        o.status.success(),
        "{:?}: {}{}",
        o.status,
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    o
}
