//! A reader that goes away (`ecsync sweep ... 2>&1 | head -2`) is no panic: a sweep stops as
//! Ctrl-C stops it (its points whole, its log row written, the same command goes on), and
//! `compare` ends quietly of SIGPIPE as Unix tools do, after it wrote its files.

mod sweeps;

use rusqlite::Connection;
use std::io::{BufRead, BufReader, Read};
use std::os::unix::process::ExitStatusExt as _;
use std::path::Path;
use std::process::Stdio;
use sweeps::{SHORT, ecsync, ok, sweep_over};

fn count(db: &Path, sql: &str) -> i64 {
    Connection::open(db)
        .unwrap()
        .query_row(sql, [], |r| r.get(0))
        .unwrap()
}

const SWEEP: &[&str] = &[
    "sweep",
    "--grid",
    "run.sync0_shift_pct=5:60:5",
    "--runs",
    "1",
    "--cycles",
    "50000",
    "--warmup-s",
    "10",
    "--methods",
    "median-fit,soem-pi",
];

/// stderr closed after two point lines: exit 130 as on Ctrl-C (not a panic's 101), the points
/// done whole, a log row saying it stopped; the same command then runs the rest.
#[test]
fn a_sweep_whose_reader_went_away_stops_as_on_ctrl_c() {
    let dir = sweeps::tmp("ecsync-pipe", "sweep");
    let db = dir.join("sweep.db");
    let mut child = ecsync()
        .args(SWEEP)
        .arg("--db")
        .arg(&db)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(child.stderr.take().unwrap()).lines();
    let mut points = 0;
    while points < 2 {
        let l = lines.next().expect("a line").unwrap();
        points += usize::from(l.starts_with("point "));
    }
    drop(lines);
    let status = child.wait().unwrap();
    assert_eq!(status.code(), Some(130), "{status:?}");
    let kept = count(&db, "SELECT count(*) FROM points");
    assert!((2..12).contains(&kept), "{kept} points kept");
    assert_eq!(count(&db, "SELECT count(*) FROM results"), 2 * kept);
    assert_eq!(count(&db, "SELECT count(*) FROM log WHERE stopped = 1"), 1);
    assert_eq!(count(&db, "SELECT points_run FROM log"), kept);
    let o = ok({
        let mut c = ecsync();
        c.args(SWEEP).arg("--db").arg(&db);
        c
    });
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(e.contains(&format!("{kept} already in")), "{e}");
    assert_eq!(count(&db, "SELECT count(*) FROM points"), 12);
}

/// Closed before the first line: no point runs, and the invocation is still logged.
#[test]
fn a_sweep_closed_from_the_start_runs_nothing_and_logs_it() {
    let dir = sweeps::tmp("ecsync-pipe", "start");
    let db = dir.join("sweep.db");
    let mut child = ecsync()
        .args(SWEEP)
        .arg("--db")
        .arg(&db)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stderr.take());
    let status = child.wait().unwrap();
    assert_eq!(status.code(), Some(130), "{status:?}");
    assert_eq!(count(&db, "SELECT count(*) FROM points"), 0);
    assert_eq!(
        count(
            &db,
            "SELECT count(*) FROM log WHERE stopped = 1 AND points_run = 0"
        ),
        1
    );
}

/// Quiet, with stdout closed: every point runs (nothing is printed until the answer), the
/// answer that finds no reader is no panic, and the log says the sweep was not stopped.
#[test]
fn a_quiet_sweep_with_stdout_closed_runs_every_point() {
    let dir = sweeps::tmp("ecsync-pipe", "quiet");
    let db = dir.join("sweep.db");
    let mut child = sweep_over(&["--grid", "run.sync0_shift_pct=10,20,30"], &db, &[])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take());
    let mut err = String::new();
    child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut err)
        .unwrap();
    let status = child.wait().unwrap();
    assert!(status.success(), "{status:?}: {err}");
    assert!(!err.contains("panicked"), "{err}");
    assert!(SHORT.contains(&"--quiet"));
    assert_eq!(count(&db, "SELECT count(*) FROM points"), 3);
    assert_eq!(count(&db, "SELECT count(*) FROM log WHERE stopped = 0"), 1);
}

/// `compare` with its stdout closed: killed by SIGPIPE (no panic on stderr), its files
/// written before the text it could not print.
#[test]
fn compare_whose_reader_went_away_ends_quietly_with_its_files_written() {
    let dir = sweeps::tmp("ecsync-pipe", "compare");
    let mut child = ecsync()
        .args([
            "compare",
            "--runs",
            "1",
            "--cycles",
            "2000",
            "--warmup-s",
            "10",
        ])
        .args(["--methods", "median-fit", "--quiet", "--out"])
        .arg(&dir)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take());
    let mut err = String::new();
    child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut err)
        .unwrap();
    let status = child.wait().unwrap();
    assert_eq!(status.signal(), Some(libc::SIGPIPE), "{status:?}: {err}");
    assert!(!err.contains("panicked"), "{err}");
    assert!(dir.join("summary.json").is_file());
}
