//! `ecsync sweep` (issue 33, acceptance 3): a sweep run whole and the same sweep as four shards
//! in four processes, merged, give the same database; Ctrl-C keeps the points done and a rerun
//! does only the rest; bad points, shards and databases are refused before any work.

mod sweeps;

use rusqlite::Connection;
use sweeps::{SHORT, ecsync, ok, sweep_over};

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

fn tmp_dir(name: &str) -> std::path::PathBuf {
    sweeps::tmp("ecsync-sweep", name)
}

/// 40 points: the letter's gain (and four more) x eight SYNC0 shifts.
const GRID_40: &[&str] = &[
    "--grid",
    "methods.median-fit.gain=0.005,0.01,0.02,0.04,0.08",
    "--grid",
    "run.sync0_shift_pct=5:40:5",
];

fn sweep(db: &Path, extra: &[&str]) -> Command {
    sweep_over(GRID_40, db, extra)
}

/// Every row of the tables a sweep's result is (not `log`, which says who ran what when),
/// in key order, as text.
fn content(db: &Path) -> Vec<String> {
    let c = Connection::open(db).unwrap();
    let mut all = Vec::new();
    for (table, order) in [
        ("sweep", "key"),
        ("points", "point"),
        ("results", "point, method"),
    ] {
        let mut q = c
            .prepare(&format!("SELECT * FROM {table} ORDER BY {order}"))
            .unwrap();
        let n = q.column_count();
        let rows = q
            .query_map([], |r| {
                let cells: Vec<String> = (0..n)
                    .map(|i| format!("{:?}", r.get_ref(i).unwrap()))
                    .collect();
                Ok(format!("{table}: {}", cells.join(" | ")))
            })
            .unwrap();
        all.extend(rows.map(Result::unwrap));
    }
    all
}

/// Starts every command of `cmds` at once (their output unread, their errors kept) and waits
/// for all: each must succeed (`what` names the run in the message, with its place).
fn all_at_once(cmds: impl IntoIterator<Item = Command>, what: &str) {
    let children: Vec<_> = cmds
        .into_iter()
        .map(|mut c| {
            c.stdout(Stdio::null())
                .stderr(Stdio::piped())
                .spawn()
                .unwrap()
        })
        .collect();
    for (i, c) in children.into_iter().enumerate() {
        let o = c.wait_with_output().unwrap();
        assert!(
            o.status.success(),
            "{what}, process {i}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
    }
}

fn count(db: &Path, sql: &str) -> i64 {
    Connection::open(db)
        .unwrap()
        .query_row(sql, [], |r| r.get(0))
        .unwrap()
}

#[test]
fn forty_points_whole_and_as_four_merged_shards_are_the_same_database() {
    let dir = tmp_dir("shards");
    let whole = dir.join("whole.db");
    let o = ok(sweep(&whole, &[]));
    let answer = String::from_utf8_lossy(&o.stdout);
    assert!(answer.starts_with("Answer: "), "{answer}");
    assert_eq!(count(&whole, "SELECT count(*) FROM points"), 40);
    assert_eq!(count(&whole, "SELECT count(*) FROM sweep_results"), 80);
    // Four processes at once, each its share.
    let shards: Vec<PathBuf> = (0..4).map(|i| dir.join(format!("shard-{i}.db"))).collect();
    all_at_once(
        shards
            .iter()
            .enumerate()
            .map(|(i, db)| sweep(db, &["--shard", &format!("{i}/4"), "--threads", "1"])),
        "shards",
    );
    for (i, shard) in shards.iter().enumerate() {
        assert_eq!(count(shard, "SELECT count(*) FROM points"), 10);
        let mine = count(
            shard,
            &format!("SELECT count(*) FROM points WHERE point % 4 = {i}"),
        );
        assert_eq!(mine, 10, "shard {i} ran its own points");
    }
    let merged = dir.join("merged.db");
    let mut m = ecsync();
    m.args(["sweep", "merge", "--db"])
        .arg(&merged)
        .args(&shards);
    let o = ok(m);
    // The same answer, and the same tables, row for row.
    assert_eq!(String::from_utf8_lossy(&o.stdout), answer);
    let (a, b) = (content(&whole), content(&merged));
    assert_eq!(a.len(), b.len());
    for (x, y) in a.iter().zip(&b) {
        assert_eq!(x, y);
    }
    assert_eq!(count(&merged, "SELECT count(*) FROM log"), 4);
    // A shard merged twice adds nothing; a shard of another sweep is refused.
    let mut again = ecsync();
    again
        .args(["sweep", "merge", "--db"])
        .arg(&merged)
        .arg(&shards[0]);
    ok(again);
    assert_eq!(content(&merged), a);
    let other = dir.join("other.db");
    let mut c = ecsync();
    c.args(["sweep", "--grid", "run.sync0_shift_pct=10"])
        .args(SHORT)
        .arg("--db")
        .arg(&other);
    ok(c);
    let o = ecsync()
        .args(["sweep", "merge", "--db"])
        .arg(&merged)
        .arg(&other)
        .output()
        .unwrap();
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && e.contains("another sweep"), "{e}");
}

/// Ctrl-C after some points: exit 130, those points kept whole; the same command again runs
/// the others only (the log says how many) and leaves the first ones' rows as they were.
#[test]
fn ctrl_c_keeps_the_points_done_and_a_rerun_does_only_the_rest() {
    let dir = tmp_dir("interrupt");
    let db = dir.join("sweep.db");
    // Longer points, with a line each on stderr (no --quiet).
    let args = [
        "sweep",
        "--grid",
        "run.sync0_shift_pct=5:60:5",
        "--runs",
        "1",
        "--cycles",
        "200000",
        "--warmup-s",
        "10",
        "--methods",
        "median-fit,soem-pi",
    ];
    let mut child = ecsync()
        .args(args)
        .arg("--db")
        .arg(&db)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(child.stderr.take().unwrap()).lines();
    let mut seen = Vec::new();
    while seen
        .iter()
        .filter(|l: &&String| l.starts_with("point "))
        .count()
        < 2
    {
        let l = lines.next().expect("a line").unwrap();
        seen.push(l);
    }
    // SAFETY: plain FFI call on the pid of a child not yet waited for.
    assert_eq!(unsafe { libc::kill(child.id() as i32, libc::SIGINT) }, 0);
    let rest: Vec<String> = lines.map(Result::unwrap).collect();
    let status = child.wait().unwrap();
    assert_eq!(status.code(), Some(130), "{seen:?} {rest:?}");
    assert!(
        rest.iter()
            .any(|l| l.contains("stopped;") && l.contains("the same command goes on")),
        "{rest:?}"
    );
    let kept = count(&db, "SELECT count(*) FROM points");
    assert!((2..12).contains(&kept), "{kept} points kept");
    // Every point kept is whole: its two methods' rows are there.
    assert_eq!(count(&db, "SELECT count(*) FROM results"), 2 * kept);
    let before = content(&db);
    let o = ok({
        let mut c = ecsync();
        c.args(args).arg("--db").arg(&db);
        c
    });
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(
        e.contains(&format!(
            "12 points over run.sync0_shift_pct, {kept} already in"
        )),
        "{e}"
    );
    assert_eq!(count(&db, "SELECT count(*) FROM points"), 12);
    let ran = count(
        &db,
        "SELECT points_run FROM log ORDER BY invocation DESC LIMIT 1",
    );
    assert_eq!(ran, 12 - kept, "the rerun ran only the points not done");
    let after = content(&db);
    for row in before.iter().filter(|r| !r.starts_with("sweep:")) {
        assert!(after.contains(row), "a kept row changed: {row}");
    }
}

/// What is wrong is named before any point runs: a field the scenario does not have, a value
/// it refuses, a bad shard, a database of another sweep.
#[test]
fn bad_points_shards_and_databases_are_refused_first() {
    let dir = tmp_dir("bad");
    let db = dir.join("sweep.db");
    let run = |args: &[&str]| {
        let o = ecsync()
            .arg("sweep")
            .args(args)
            .args(SHORT)
            .arg("--db")
            .arg(&db)
            .output()
            .unwrap();
        assert_eq!(o.status.code(), Some(1), "{args:?}");
        String::from_utf8_lossy(&o.stderr).to_string()
    };
    let e = run(&["--grid", "run.sync0_shift=10,20"]);
    assert!(e.contains("sync0_shift") && e.contains("fix:"), "{e}");
    let e = run(&["--grid", "methods.median-fit.gain=0.01,2"]);
    assert!(
        e.contains("point 1") && e.contains("gain") && e.contains("fix:"),
        "{e}"
    );
    // The point is named once and the file without a line: the text checked is the point's,
    // made from the file without its comments and in another order, so no line of it is one
    // of the file's (this gain is on line 187 of presets/paper-2024.toml; the error said 33).
    assert_eq!(e.matches("point 1").count(), 1, "{e}");
    assert!(
        e.contains("(methods.median-fit.gain=2): preset paper-2024: methods.median-fit.gain: "),
        "{e}"
    );
    let e = run(&["--grid", "run.sync0_shift_pct=10", "--shard", "4/4"]);
    assert!(e.contains("--shard 4/4") && e.contains("fix:"), "{e}");
    let e = run(&["--grid", "run.sync0_shift_pct=40:10:5"]);
    assert!(e.contains("STOP not below START"), "{e}");
    assert!(!db.exists(), "nothing made before the points were checked");
    ok({
        let mut c = ecsync();
        c.args(["sweep", "--grid", "run.sync0_shift_pct=10"])
            .args(SHORT)
            .arg("--db")
            .arg(&db);
        c
    });
    let e = run(&["--grid", "run.sync0_shift_pct=20"]);
    assert!(
        e.contains("holds another sweep") && e.contains("fix:"),
        "{e}"
    );
    // A database in a folder that is not there: named, with the cause and the fix.
    let nowhere = dir.join("no-such-folder").join("sweep.db");
    let o = ecsync()
        .args(["sweep", "--grid", "run.sync0_shift_pct=10"])
        .args(SHORT)
        .arg("--db")
        .arg(&nowhere)
        .output()
        .unwrap();
    let e = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{e}");
    assert!(
        e.contains(&format!("--db: cannot open {}: ", nowhere.display()))
            && e.contains("; fix: give a file in a folder that exists"),
        "{e}"
    );
}

/// Four shards started together into one new database (the same command run twice is the
/// same race): each finds the sweep the first made and adds its points, and the database
/// equals the sweep run whole. Before, all but one failed at once ("table sweep already
/// exists", or "the database has no sweep.points: not a sweep database") in every try.
#[test]
fn shards_started_together_into_one_database_all_run() {
    let dir = tmp_dir("one-db");
    let grid = ["--grid", "run.sync0_shift_pct=5:40:5"];
    let whole = dir.join("whole.db");
    ok(sweep_over(&grid, &whole, &[]));
    for attempt in 0..3 {
        let db = dir.join(format!("together-{attempt}.db"));
        all_at_once(
            (0..4).map(|i| {
                sweep_over(
                    &grid,
                    &db,
                    &["--shard", &format!("{i}/4"), "--threads", "1"],
                )
            }),
            &format!("attempt {attempt}"),
        );
        assert_eq!(content(&db), content(&whole), "attempt {attempt}");
        assert_eq!(count(&db, "SELECT count(*) FROM log"), 4);
    }
}

/// The same sweep started twice at once into one new database: both finish, each point is
/// stored once (the log's points add up to the sweep's), and the database equals the sweep
/// run whole. Before, the second failed with "UNIQUE constraint failed: points.point" at the
/// first point the other had stored, its log row unwritten.
#[test]
fn the_same_sweep_twice_at_once_stores_each_point_once() {
    let dir = tmp_dir("twice");
    let grid = ["--grid", "run.sync0_shift_pct=5:40:5"];
    let whole = dir.join("whole.db");
    ok(sweep_over(&grid, &whole, &[]));
    for attempt in 0..3 {
        let db = dir.join(format!("twice-{attempt}.db"));
        all_at_once(
            (0..2).map(|_| sweep_over(&grid, &db, &["--threads", "1"])),
            &format!("attempt {attempt}"),
        );
        assert_eq!(content(&db), content(&whole), "attempt {attempt}");
        assert_eq!(count(&db, "SELECT sum(points_run) FROM log"), 8);
        assert_eq!(count(&db, "SELECT count(*) FROM log"), 2);
    }
}
