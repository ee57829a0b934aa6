//! A sweep's results in SQLite: one row per point (its parameters, scenario, seed and
//! verdict) and one per point and method (the ground truth's figures and the method's place),
//! so that a sweep resumes where it stopped, shards merge, and users query it with SQL or
//! pandas (`pd.read_sql("select * from sweep_results", con)`).
//!
//! Tables: `sweep` (what the sweep is: base scenario, keys, every point; a database only ever
//! takes points of the sweep it was made for), `points`, `results`, the view `sweep_results`
//! (the two joined, without the scenario text), and `log` (who ran what when: the only table
//! that differs between a whole run and merged shards).

use super::grid::{Points, show};
use anyhow::{Context, Result, bail};
use ecsync_lab::report::SummaryOut;
/// One method at one point, as the sweep's answer and its report read it.
pub use ecsync_lab::sweep_report::Row as ResultRow;
use rusqlite::{Connection, OptionalExtension, params, types::Value as SqlValue};
use std::collections::BTreeSet;
use std::path::Path;
use toml::Value;

/// The database's layout version (`sweep.format`): 2 added `results.not_ranked`, 3
/// `results.warnings`.
const FORMAT: &str = "3";

/// What a sweep is: the same base and points, the same sweep.
#[derive(Debug, Clone)]
pub struct Meta {
    /// Where the base scenario came from.
    pub base_name: String,
    /// The base scenario's TOML, with the command line's settings written in.
    pub base_toml: String,
    /// Every point.
    pub points: Points,
}

impl PartialEq for Meta {
    /// The same base scenario and the same points (by their canonical text: a value's type
    /// is as the grid gave it).
    fn eq(&self, other: &Meta) -> bool {
        self.base_toml == other.base_toml && self.points.canonical() == other.points.canonical()
    }
}

impl Meta {
    /// What makes `self` another sweep than `other`, in words: each differing setting of the
    /// base scenario ("run.cycles (50000 HERE, 100000 THERE)", the first few), or else the
    /// points; `here` and `there` name the two sides.
    pub fn differences(&self, other: &Meta, here: &str, there: &str) -> String {
        let mut found: Vec<(String, String, String)> = Vec::new();
        match (
            self.base_toml.parse::<toml::Table>(),
            other.base_toml.parse::<toml::Table>(),
        ) {
            (Ok(a), Ok(b)) => table_differences("", &a, &b, &mut found),
            _ => found.push(("the base scenario".into(), "one".into(), "another".into())),
        }
        let (a, b) = (&self.points, &other.points);
        if a.keys != b.keys {
            found.push((
                "the swept keys".into(),
                a.keys.join(", "),
                b.keys.join(", "),
            ));
        } else if a.rows.len() != b.rows.len() {
            found.push((
                "the points".into(),
                format!("{} points", a.rows.len()),
                format!("{}", b.rows.len()),
            ));
        } else if let Some(i) = (0..a.rows.len()).find(|&i| a.rows[i] != b.rows[i]) {
            found.push((format!("point {i}"), a.describe(i), b.describe(i)));
        }
        let n = found.len();
        let mut words: Vec<String> = found
            .into_iter()
            .take(3)
            .map(|(what, x, y)| format!("{what} ({x} {here}, {y} {there})"))
            .collect();
        if n > 3 {
            words.push(format!(
                "and {}",
                ecsync_lab::scenario::plural((n - 3) as u64, "more setting", "more settings")
            ));
        }
        words.join(", ")
    }
}

/// The fields of `a` and `b` (under `path`) whose values differ, as (field, a's, b's).
fn table_differences(
    path: &str,
    a: &toml::Table,
    b: &toml::Table,
    found: &mut Vec<(String, String, String)>,
) {
    let keys: std::collections::BTreeSet<&String> = a.keys().chain(b.keys()).collect();
    for k in keys {
        let field = if path.is_empty() {
            k.clone()
        } else {
            format!("{path}.{k}")
        };
        match (a.get(k), b.get(k)) {
            (Some(Value::Table(x)), Some(Value::Table(y))) => {
                table_differences(&field, x, y, found);
            }
            (x, y) if x != y => {
                let text = |v: Option<&Value>| match v {
                    None => "not set".to_string(),
                    Some(Value::Table(_)) => "a table".to_string(),
                    Some(v) => show(v),
                };
                found.push((field, text(x), text(y)));
            }
            _ => {}
        }
    }
}

/// The results columns: name, SQL type, and what they are (the book's table, `sweep --help`).
pub const RESULT_COLUMNS: &[(&str, &str, &str)] = &[
    (
        "rank",
        "INTEGER",
        "place in the point's ranking, 1 best (NULL: not ranked)",
    ),
    (
        "not_ranked",
        "TEXT",
        "why the verdict left the method out, in compare's words (NULL: ranked, or no ranking)",
    ),
    ("recommended", "INTEGER", "1 for the point's pick"),
    (
        "within_noise",
        "INTEGER",
        "1 when within run-to-run noise of the pick",
    ),
    (
        "late_frames",
        "INTEGER",
        "cycles with a frame after a drive's SYNC0",
    ),
    ("lost_frames", "INTEGER", "frames lost"),
    (
        "bad_wkc",
        "INTEGER",
        "cycles with a wrong LRW working counter",
    ),
    (
        "wild_schedule_cycles",
        "INTEGER",
        "cycles an unstable method's next start was held",
    ),
    (
        "sync0_missed",
        "INTEGER",
        "SYNC0 pulses without new outputs, all slaves",
    ),
    (
        "sync0_shift_pct",
        "REAL",
        "the SYNC0 shift run, % of the cycle",
    ),
    (
        "smallest_safe_shift_pct",
        "REAL",
        "the smallest SYNC0 shift without a late frame, %",
    ),
    (
        "holds_target",
        "INTEGER",
        "1 when the mean phase is within 10 % of the margin of the target",
    ),
    (
        "phase_mean_ns",
        "REAL",
        "the frame's arrival at the reference against the DC grid, mean",
    ),
    ("phase_error_p999_ns", "REAL", "p99.9 of |phase - target|"),
    (
        "slave_spread_p999_ns",
        "REAL",
        "p99.9 of |slave - reference| system time",
    ),
    (
        "margin_min_ns",
        "REAL",
        "the worst slave's smallest SYNC0 margin",
    ),
    ("m_rs_mean_ns", "REAL", "M-rS MMean (the letter's Table 1)"),
    ("m_rs_std_ns", "REAL", "M-rS MStd"),
    ("m_rs_max_ns", "REAL", "M-rS MMax"),
    ("m_rs_min_ns", "REAL", "M-rS MMin"),
    ("rs_is_mean_ns", "REAL", "rS-IS MMean"),
    ("rs_is_std_ns", "REAL", "rS-IS MStd"),
    ("rs_is_max_ns", "REAL", "rS-IS MMax"),
    ("rs_is_min_ns", "REAL", "rS-IS MMin"),
    ("lock_ms", "REAL", "bring-up time to DC lock"),
    ("cycles", "INTEGER", "recorded cycles, all runs"),
    (
        "warnings",
        "TEXT",
        "the kinds of compare's warnings about the method, comma-separated (settling: still pulling in as the recording began)",
    ),
];

/// An SQL identifier, quoted (parameter keys hold dots and dashes).
fn ident(s: &str) -> String {
    format!("\"{}\"", s.replace('"', "\"\""))
}

fn sql_of(v: &Value) -> SqlValue {
    match v {
        Value::Integer(i) => SqlValue::Integer(*i),
        Value::Float(f) => SqlValue::Real(*f),
        Value::Boolean(b) => SqlValue::Integer(i64::from(*b)),
        v => SqlValue::Text(show(v)),
    }
}

/// An open sweep database.
pub struct Store {
    conn: Connection,
}

impl Store {
    /// Opens `path` for `meta`'s sweep, making the tables in a new database. A database of
    /// another sweep is refused: mixing them would give a table nobody can read.
    pub fn open(path: &Path, meta: &Meta) -> Result<Store> {
        let conn = Connection::open(path)
            .map_err(|e| {
                anyhow::anyhow!(
                    "--db: cannot open {}: {e}; fix: give a file in a folder that exists and you may write to",
                    path.display()
                )
            })?;
        // Another sweep on the same file (shards side by side, the same command twice) may
        // hold its lock: wait for it, from the first statement on. Switching a new database
        // to WAL takes the lock too, and SQLite may answer it busy without waiting: tried
        // again for as long.
        let wait = std::time::Duration::from_secs(60);
        let cannot_write = |e: rusqlite::Error| {
            anyhow::anyhow!(
                "--db: cannot write {}: {e}; fix: give a file in a folder that exists and you may write to",
                path.display()
            )
        };
        conn.busy_timeout(wait).map_err(cannot_write)?;
        let t0 = std::time::Instant::now();
        while let Err(e) = conn.pragma_update(None, "journal_mode", "WAL") {
            let busy = matches!(
                e.sqlite_error_code(),
                Some(rusqlite::ErrorCode::DatabaseBusy | rusqlite::ErrorCode::DatabaseLocked)
            );
            if !busy || t0.elapsed() > wait {
                return Err(cannot_write(e));
            }
            std::thread::sleep(std::time::Duration::from_millis(10));
        }
        let store = Store { conn };
        // Looking for the tables and making them is one write transaction: two sweeps started
        // on one new database (shards run side by side into one file, or the same command
        // twice) both found no tables, and all but one failed ("table sweep already exists",
        // or "no sweep.points" when read between the tables and their rows). The second waits
        // for the first (SQLite's busy timeout) and finds its sweep.
        store
            .conn
            .execute_batch("BEGIN IMMEDIATE")
            .map_err(cannot_write)?;
        match store.open_in_transaction(path, meta) {
            Ok(()) => store.conn.execute_batch("COMMIT")?,
            Err(e) => {
                let _ = store.conn.execute_batch("ROLLBACK");
                return Err(e);
            }
        }
        Ok(store)
    }

    /// [`Store::open`]'s look for the sweep, in its transaction.
    fn open_in_transaction(&self, path: &Path, meta: &Meta) -> Result<()> {
        match self.meta()? {
            None => self
                .create(meta)
                .with_context(|| format!("--db: cannot create the tables in {}", path.display()))?,
            Some(m) if m == *meta => {}
            Some(m) => bail!(
                "--db: {} holds another sweep ({} over {} of {}); it differs in {}; fix: give another --db, or the database's settings and points to go on with it",
                path.display(),
                ecsync_lab::scenario::plural(m.points.rows.len() as u64, "point", "points"),
                m.points.keys.join(", "),
                m.base_name,
                meta.differences(&m, "here", "in the database")
            ),
        }
        Ok(())
    }

    /// The sweep this database is for (`None`: a new database).
    fn meta(&self) -> Result<Option<Meta>> {
        let has: bool = self.conn.query_row(
            "SELECT count(*) FROM sqlite_master WHERE type = 'table' AND name = 'sweep'",
            [],
            |r| r.get::<_, i64>(0).map(|n| n > 0),
        )?;
        if !has {
            return Ok(None);
        }
        let get = |k: &str| -> Result<String> {
            self.conn
                .query_row("SELECT value FROM sweep WHERE key = ?1", [k], |r| r.get(0))
                .optional()?
                .with_context(|| format!("the database has no sweep.{k}: not a sweep database"))
        };
        if get("format")? != FORMAT {
            bail!(
                "the database is of another format than this ecsync's ({FORMAT}); fix: give another --db (this ecsync runs its points again into a new one)"
            );
        }
        let points = get("points")?;
        Ok(Some(Meta {
            base_name: get("base_name")?,
            base_toml: get("base_toml")?,
            points: parse_canonical(&points)?,
        }))
    }

    fn create(&self, meta: &Meta) -> Result<()> {
        let keys: String = meta
            .points
            .keys
            .iter()
            .map(|k| format!("{} ,", ident(k)))
            .collect();
        let results: String = RESULT_COLUMNS
            .iter()
            .map(|(n, t, _)| format!(", {n} {t}"))
            .collect();
        let view_keys: String = meta
            .points
            .keys
            .iter()
            .map(|k| format!("p.{}, ", ident(k)))
            .collect();
        let view_results: String = RESULT_COLUMNS
            .iter()
            .map(|(n, _, _)| format!(", r.{n}"))
            .collect();
        // In the caller's transaction (see `open`): the tables and their rows come whole.
        self.conn.execute_batch(&format!(
            "CREATE TABLE sweep (key TEXT PRIMARY KEY, value TEXT NOT NULL);
             CREATE TABLE points (point INTEGER PRIMARY KEY, {keys} seed INTEGER NOT NULL,
                 recommended TEXT, ranking TEXT NOT NULL, reason TEXT NOT NULL,
                 warnings TEXT NOT NULL, scenario TEXT NOT NULL);
             CREATE TABLE results (point INTEGER NOT NULL REFERENCES points(point),
                 method TEXT NOT NULL {results}, PRIMARY KEY (point, method));
             CREATE TABLE log (invocation INTEGER PRIMARY KEY, shard TEXT NOT NULL,
                 started_unix_s INTEGER NOT NULL, points_run INTEGER NOT NULL,
                 wall_s REAL NOT NULL, stopped INTEGER NOT NULL);
             CREATE VIEW sweep_results AS SELECT p.point, {view_keys} r.method {view_results},
                 p.seed FROM points p JOIN results r ON r.point = p.point;"
        ))?;
        let mut put = self
            .conn
            .prepare("INSERT INTO sweep (key, value) VALUES (?1, ?2)")?;
        put.execute(["format", FORMAT])?;
        put.execute(["base_name", &meta.base_name])?;
        put.execute(["base_toml", &meta.base_toml])?;
        put.execute(["points", &meta.points.canonical()])?;
        put.execute(["ecsync_version", env!("CARGO_PKG_VERSION")])?;
        Ok(())
    }

    /// The points done.
    pub fn done(&self) -> Result<BTreeSet<usize>> {
        let mut q = self.conn.prepare("SELECT point FROM points")?;
        let rows = q.query_map([], |r| r.get::<_, i64>(0))?;
        Ok(rows
            .collect::<Result<Vec<_>, _>>()?
            .into_iter()
            .map(|p| p as usize)
            .collect())
    }

    /// How many different seeds the points done ran with.
    pub fn seeds(&self) -> Result<usize> {
        let n: i64 = self
            .conn
            .query_row("SELECT count(DISTINCT seed) FROM points", [], |r| r.get(0))?;
        Ok(n as usize)
    }

    /// Stores point `point` (its scenario `toml`) and its comparison's figures, in one
    /// transaction: a point is in the database whole or not at all. `false`: another sweep on
    /// this database (the same command run twice) stored it first; its rows are kept (a point's
    /// comparison is deterministic: they are these).
    pub fn put(
        &mut self,
        point: usize,
        values: &[Value],
        toml: &str,
        out: &SummaryOut,
    ) -> Result<bool> {
        let tx = self.conn.transaction()?;
        let mut row: Vec<SqlValue> = vec![SqlValue::Integer(point as i64)];
        row.extend(values.iter().map(sql_of));
        let rec = &out.recommendation;
        row.push(SqlValue::Integer(out.seed as i64));
        row.push(if rec.ranking.is_empty() {
            SqlValue::Null
        } else {
            SqlValue::Text(rec.method.clone())
        });
        row.push(SqlValue::Text(rec.ranking.join(", ")));
        // The verdict's reason, then why a method is not ranked, as `compare` prints them.
        let mut reason = rec.reason.clone();
        for n in &rec.not_ranked {
            reason.push_str(&format!(" Not ranked: {}.", n.why));
        }
        row.push(SqlValue::Text(reason));
        let warnings: Vec<&str> = out.warnings.iter().map(|w| w.kind).collect();
        row.push(SqlValue::Text(warnings.join(", ")));
        row.push(SqlValue::Text(toml.to_string()));
        let marks = vec!["?"; row.len()].join(", ");
        let stored = tx.execute(
            &format!("INSERT OR IGNORE INTO points VALUES ({marks})"),
            rusqlite::params_from_iter(row),
        )?;
        if stored == 0 {
            return Ok(false);
        }
        let marks = vec!["?"; RESULT_COLUMNS.len() + 2].join(", ");
        {
            let mut ins = tx.prepare(&format!("INSERT INTO results VALUES ({marks})"))?;
            for (name, m) in &out.methods {
                let rank = rec.ranking.iter().position(|r| r == name);
                let g = &m.ground_truth;
                let missed: u64 = g.per_slave.iter().map(|s| s.sync0_missed).sum();
                let v: Vec<SqlValue> = vec![
                    SqlValue::Integer(point as i64),
                    SqlValue::Text(name.clone()),
                    rank.map_or(SqlValue::Null, |r| SqlValue::Integer(r as i64 + 1)),
                    rec.not_ranked
                        .iter()
                        .find(|n| &n.method == name)
                        .map_or(SqlValue::Null, |n| SqlValue::Text(n.why.clone())),
                    SqlValue::Integer(i64::from(rank == Some(0))),
                    SqlValue::Integer(i64::from(rec.within_noise.contains(name))),
                    SqlValue::Integer(g.late_frames as i64),
                    SqlValue::Integer(g.lost_frames as i64),
                    SqlValue::Integer(g.bad_wkc as i64),
                    SqlValue::Integer(m.wild_schedule_cycles as i64),
                    SqlValue::Integer(missed as i64),
                    SqlValue::Real(g.sync0_shift_pct),
                    SqlValue::Real(g.smallest_safe_shift_pct),
                    SqlValue::Integer(i64::from(g.holds_target)),
                    SqlValue::Real(g.phase.mean),
                    SqlValue::Real(g.phase_error.p999_abs),
                    SqlValue::Real(g.slave_ref_diff.p999_abs),
                    SqlValue::Real(g.sync0_margin.min),
                    SqlValue::Real(m.m_rs.mean),
                    SqlValue::Real(m.m_rs.std),
                    SqlValue::Real(m.m_rs.max),
                    SqlValue::Real(m.m_rs.min),
                    SqlValue::Real(m.rs_is.mean),
                    SqlValue::Real(m.rs_is.std),
                    SqlValue::Real(m.rs_is.max),
                    SqlValue::Real(m.rs_is.min),
                    SqlValue::Real(m.lock_ms),
                    SqlValue::Integer(m.cycles_done as i64),
                    SqlValue::Text(
                        out.warnings
                            .iter()
                            .filter(|w| w.method.as_deref() == Some(name.as_str()))
                            .map(|w| w.kind)
                            .collect::<Vec<_>>()
                            .join(", "),
                    ),
                ];
                ins.execute(rusqlite::params_from_iter(v))?;
            }
        }
        tx.commit()?;
        Ok(true)
    }

    /// Whether point `point` is in the database (another sweep on it may have stored it since
    /// this one looked).
    pub fn has(&self, point: usize) -> Result<bool> {
        let n: i64 = self.conn.query_row(
            "SELECT count(*) FROM points WHERE point = ?1",
            [point as i64],
            |r| r.get(0),
        )?;
        Ok(n > 0)
    }

    /// Records one invocation: the shard it ran, how many points, how long, whether stopped.
    pub fn log(
        &self,
        shard: &str,
        started_unix_s: i64,
        points_run: usize,
        wall_s: f64,
        stopped: bool,
    ) -> Result<()> {
        self.conn.execute(
            "INSERT INTO log (shard, started_unix_s, points_run, wall_s, stopped) VALUES (?1, ?2, ?3, ?4, ?5)",
            params![shard, started_unix_s, points_run as i64, wall_s, stopped],
        )?;
        Ok(())
    }

    /// The per-method rows of every point done, in point and method order, for the sweep's
    /// answer and its report (`good` left false: the answer decides it, `answer::good`).
    pub fn rows(&self) -> Result<Vec<ResultRow>> {
        let mut q = self.conn.prepare(
            "SELECT point, method, late_frames, lost_frames, smallest_safe_shift_pct,
                    phase_error_p999_ns, holds_target, slave_spread_p999_ns, rank, not_ranked,
                    warnings
             FROM results ORDER BY point, method",
        )?;
        let rows = q.query_map([], |r| {
            Ok(ResultRow {
                point: r.get::<_, i64>(0)? as usize,
                method: r.get(1)?,
                late_frames: r.get::<_, i64>(2)? as u64,
                lost_frames: r.get::<_, i64>(3)? as u64,
                safe_shift_pct: r.get::<_, Option<f64>>(4)?.unwrap_or(f64::NAN),
                phase_error_p999_ns: r.get::<_, Option<f64>>(5)?.unwrap_or(f64::NAN),
                holds_target: r.get::<_, i64>(6)? != 0,
                slave_spread_p999_ns: r.get::<_, Option<f64>>(7)?.unwrap_or(f64::NAN),
                rank: r.get::<_, Option<i64>>(8)?.map(|k| k as u32),
                not_ranked: r.get(9)?,
                settling: r.get::<_, String>(10)?.split(", ").any(|k| k == "settling"),
                good: false,
            })
        })?;
        Ok(rows.collect::<Result<_, _>>()?)
    }

    /// Copies the points and results of the sweep database `src` into this one, and its log.
    /// A point both hold must hold the same figures (they ran the same deterministic
    /// comparison); else the merge stops, naming it.
    pub fn merge_from(&mut self, src: &Path) -> Result<usize> {
        let before = self.done()?.len();
        let path = src.to_str().context("a database path that is not UTF-8")?;
        self.conn.execute("ATTACH DATABASE ?1 AS src", [path])?;
        let r = (|| -> Result<()> {
            for table in ["points", "results"] {
                let key = if table == "points" {
                    "point"
                } else {
                    "point, method"
                };
                let overlap: i64 = self.conn.query_row(
                    &format!(
                        "SELECT count(*) FROM src.{table} s JOIN main.{table} m USING ({key})"
                    ),
                    [],
                    |r| r.get(0),
                )?;
                let same: i64 = self.conn.query_row(
                    &format!("SELECT count(*) FROM (SELECT * FROM src.{table} INTERSECT SELECT * FROM main.{table})"),
                    [],
                    |r| r.get(0),
                )?;
                if overlap != same {
                    bail!(
                        "{} and the databases before it differ on {} {table} rows they both hold: were they run by different ecsync versions? fix: run those points again with one binary",
                        src.display(),
                        overlap - same
                    );
                }
            }
            self.conn.execute_batch(
                "BEGIN;
                 INSERT OR IGNORE INTO main.points SELECT * FROM src.points;
                 INSERT OR IGNORE INTO main.results SELECT * FROM src.results;
                 INSERT INTO main.log (shard, started_unix_s, points_run, wall_s, stopped)
                     SELECT shard, started_unix_s, points_run, wall_s, stopped FROM src.log
                     ORDER BY invocation;
                 COMMIT;",
            )?;
            Ok(())
        })();
        self.conn.execute("DETACH DATABASE src", [])?;
        r?;
        Ok(self.done()?.len() - before)
    }
}

/// The sweep a database at `path` holds (for `merge`: the first input names the sweep).
pub fn read_meta(path: &Path) -> Result<Meta> {
    if !path.is_file() {
        bail!(
            "{}: no such file; fix: give the shards' databases",
            path.display()
        );
    }
    Ok(read(path)?.1)
}

/// The sweep database at `path`, opened to read only (the report changes nothing in it), and
/// the sweep it holds.
pub fn read(path: &Path) -> Result<(Store, Meta)> {
    let conn = Connection::open_with_flags(path, rusqlite::OpenFlags::SQLITE_OPEN_READ_ONLY)
        .map_err(|e| {
            anyhow::anyhow!(
                "cannot open {}: {e}; fix: give a database `ecsync sweep --db` wrote",
                path.display()
            )
        })?;
    let store = Store { conn };
    let meta = store
        .meta()
        .with_context(|| format!("{}", path.display()))?
        .with_context(|| format!("{}: not a sweep database (no sweep table)", path.display()))?;
    Ok((store, meta))
}

/// [`Points::canonical`] read back.
fn parse_canonical(s: &str) -> Result<Points> {
    let mut lines = s.split('\n');
    let keys: Vec<String> = lines
        .next()
        .unwrap_or_default()
        .split('\u{1f}')
        .map(str::to_string)
        .collect();
    let rows = lines
        .map(|l| l.split('\u{1f}').map(super::grid::value_of).collect())
        .collect();
    Ok(Points { keys, rows })
}
