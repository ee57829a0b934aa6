//! `ecsync sweep --report` and `ecsync sweep report`: the files are there, the heat map has a
//! cell per point, the plots mark the point an SQL query over the database finds best (the
//! truth here is the query, not the code under test), a merged database gives the same bytes
//! as the sweep run whole, and a folder that cannot take the report fails before any point.

mod sweeps;

use rusqlite::Connection;
use sweeps::{ecsync, ok, sweep_over};

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::process::Command;

fn tmp_dir(name: &str) -> std::path::PathBuf {
    sweeps::tmp("ecsync-sweeprep", name)
}

/// Six points: three gains x two SYNC0 shifts. At 5 % frames come late (the smallest safe
/// shift is near 7 % here), so half the points are not good and the report has to draw both.
const GRID: &[&str] = &[
    "--grid",
    "methods.median-fit.gain=0.005,0.01,0.02",
    "--grid",
    "run.sync0_shift_pct=5,30",
];

fn sweep(db: &Path, extra: &[&str]) -> Command {
    sweep_over(GRID, db, extra)
}

fn read(p: &Path) -> String {
    std::fs::read_to_string(p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

/// The good points' best, by SQL: no late or lost frame, ranked, on its target; the smallest
/// safe shift, then the smallest phase error (ties: the method, then the point, first by
/// name and number). `method` narrows it to one method.
fn best_by_sql(db: &Path, method: Option<&str>) -> (String, i64) {
    let c = Connection::open(db).unwrap();
    c.query_row(
        "SELECT method, point FROM sweep_results
         WHERE rank IS NOT NULL AND late_frames = 0 AND lost_frames = 0 AND holds_target = 1
           AND smallest_safe_shift_pct IS NOT NULL AND (?1 IS NULL OR method = ?1)
         ORDER BY smallest_safe_shift_pct, phase_error_p999_ns, method, point LIMIT 1",
        [method],
        |r| Ok((r.get(0)?, r.get(1)?)),
    )
    .unwrap()
}

/// Whether each (point, method) is good, by SQL: no late or lost frame, ranked, on target.
fn good_by_sql(db: &Path) -> BTreeSet<(String, String)> {
    let c = Connection::open(db).unwrap();
    let mut q = c
        .prepare(
            "SELECT point, method FROM sweep_results
             WHERE rank IS NOT NULL AND late_frames = 0 AND lost_frames = 0 AND holds_target = 1
               AND smallest_safe_shift_pct IS NOT NULL",
        )
        .unwrap();
    q.query_map([], |r| Ok((r.get::<_, i64>(0)?.to_string(), r.get(1)?)))
        .unwrap()
        .map(Result::unwrap)
        .collect()
}

/// The (point, method) of every element of `svg` drawn as good (`data-good="1"`) or not.
fn drawn_good(svg: &str, good: bool) -> BTreeSet<(String, String)> {
    let marker = format!("data-good=\"{}\"", u8::from(good));
    attrs(svg, &marker, "data-point")
        .into_iter()
        .zip(attrs(svg, &marker, "data-method"))
        .collect()
}

/// The values of `attr` on every element of `svg` that carries `marker`.
fn attrs(svg: &str, marker: &str, attr: &str) -> Vec<String> {
    svg.lines()
        .filter(|l| l.contains(marker))
        .filter_map(|l| {
            let k = l.find(&format!(" {attr}=\""))? + attr.len() + 3;
            Some(l[k..k + l[k..].find('"')?].to_string())
        })
        .collect()
}

#[test]
fn the_report_draws_every_point_and_marks_the_point_sql_finds_best() {
    let d = tmp_dir("whole");
    let db = d.join("s.db");
    let rep = d.join("report");
    let o = ok(sweep(&db, &["--report", rep.to_str().unwrap()]));
    let answer = String::from_utf8_lossy(&o.stdout).to_string();
    for f in [
        "tradeoff.svg",
        "tradeoff.png",
        "heatmap-median-fit.svg",
        "heatmap-median-fit.png",
        "heatmap-soem-pi.svg",
        "heatmap-soem-pi.png",
        "sweep.html",
    ] {
        assert!(rep.join(f).is_file(), "{f} missing");
    }
    let (method, point) = best_by_sql(&db, None);
    // The answer's first line, the trade-off's label and its marked marker name that point.
    let first = answer.lines().next().unwrap();
    assert!(
        first.starts_with(&format!("Answer: {method} at point {point} (")),
        "SQL finds {method} at point {point}; the answer says: {first}"
    );
    let tradeoff = read(&rep.join("tradeoff.svg"));
    let label = format!("best: {method} at point {point}");
    assert!(
        tradeoff.contains(&format!(">\n{label}\n</text>")),
        "no label {label:?}"
    );
    assert_eq!(tradeoff.matches("best: ").count(), 1, "one best label");
    let best_marker =
        format!("data-point=\"{point}\" data-method=\"{method}\" data-good=\"1\" data-best=\"1\"");
    assert_eq!(tradeoff.matches(&best_marker).count(), 1);
    assert_eq!(tradeoff.matches("data-best=\"1\"").count(), 1);
    // One marker per point and method.
    let conn = Connection::open(&db).unwrap();
    let results: i64 = conn
        .query_row("SELECT count(*) FROM results", [], |r| r.get(0))
        .unwrap();
    assert_eq!(results, 12);
    assert_eq!(tradeoff.matches(" data-point=\"").count(), results as usize);
    // Filled exactly where SQL finds a point good; hollow elsewhere (and there are both).
    let good = good_by_sql(&db);
    assert!(
        !good.is_empty() && good.len() < results as usize,
        "{good:?}"
    );
    assert_eq!(drawn_good(&tradeoff, true), good);
    assert_eq!(
        drawn_good(&tradeoff, false).len() + good.len(),
        results as usize
    );
    // Each heat map: one cell per point, every point once; the method's best (by SQL) outlined.
    for m in ["median-fit", "soem-pi"] {
        let svg = read(&rep.join(format!("heatmap-{m}.svg")));
        let cells = attrs(&svg, "<rect x=", "data-point");
        assert_eq!(cells.len(), 6, "{m}: {cells:?}");
        let pts: BTreeSet<i64> = cells.iter().map(|p| p.parse().unwrap()).collect();
        assert_eq!(pts, (0..6).collect(), "{m}");
        assert!(
            attrs(&svg, "<rect x=", "data-method")
                .iter()
                .all(|x| x == m)
        );
        let (_, p) = best_by_sql(&db, Some(m));
        let best = attrs(&svg, "data-best=\"1\"", "data-point");
        assert_eq!(best, [p.to_string()], "{m}'s best cell");
        assert!(svg.contains("safe shift, %"), "{m}: the colour bar's unit");
        let good_here: BTreeSet<_> = good.iter().filter(|g| g.1 == m).cloned().collect();
        assert_eq!(drawn_good(&svg, true), good_here, "{m}: coloured cells");
        assert_eq!(
            drawn_good(&svg, false).len() + good_here.len(),
            6,
            "{m}: hatched cells"
        );
    }
    // The page: the answer, the plots inline, a row per point and method.
    let html = read(&rep.join("sweep.html"));
    let escaped = answer
        .replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;");
    assert!(html.contains(&escaped), "the answer as printed");
    assert_eq!(
        html.matches("<svg").count(),
        3,
        "tradeoff and two heat maps inline"
    );
    assert_eq!(html.matches("<tr").count(), results as usize + 1);
    assert_eq!(
        html.matches("<tr class=bad>").count(),
        results as usize - good.len()
    );
    assert!(
        !html.contains("src=\"") && !html.contains("<link"),
        "self-contained"
    );
    std::fs::remove_dir_all(&d).unwrap();
}

/// Every file of `dir`, by name, with its bytes.
fn files(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut v: Vec<(String, Vec<u8>)> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| {
            let e = e.unwrap();
            (
                e.file_name().to_string_lossy().to_string(),
                std::fs::read(e.path()).unwrap(),
            )
        })
        .collect();
    v.sort();
    v
}

#[test]
fn a_merged_database_of_two_shards_gives_the_same_report_byte_for_byte() {
    let d = tmp_dir("merged");
    let whole = d.join("whole.db");
    let rep_whole = d.join("whole");
    ok(sweep(&whole, &["--report", rep_whole.to_str().unwrap()]));
    let shards: Vec<PathBuf> = (0..2).map(|i| d.join(format!("shard{i}.db"))).collect();
    for (i, s) in shards.iter().enumerate() {
        ok(sweep(s, &["--shard", &format!("{i}/2")]));
    }
    let merged = d.join("merged.db");
    ok({
        let mut c = ecsync();
        c.args(["sweep", "merge", "--db"])
            .arg(&merged)
            .args(&shards);
        c
    });
    let rep_merged = d.join("merged");
    let o = ok({
        let mut c = ecsync();
        c.args(["sweep", "report", "--db"])
            .arg(&merged)
            .arg("--out")
            .arg(&rep_merged);
        c
    });
    let a = files(&rep_whole);
    let b = files(&rep_merged);
    assert_eq!(
        a.len(),
        7,
        "{:?}",
        a.iter().map(|f| &f.0).collect::<Vec<_>>()
    );
    assert_eq!(
        a.iter().map(|f| &f.0).collect::<Vec<_>>(),
        b.iter().map(|f| &f.0).collect::<Vec<_>>()
    );
    for ((name, x), (_, y)) in a.iter().zip(&b) {
        assert!(
            x == y,
            "{name} differs between the whole run and the merged shards"
        );
    }
    // The same answer on stdout as the whole run's.
    let (method, point) = best_by_sql(&merged, None);
    assert!(
        String::from_utf8_lossy(&o.stdout)
            .starts_with(&format!("Answer: {method} at point {point} (")),
    );
    std::fs::remove_dir_all(&d).unwrap();
}

#[test]
fn a_report_folder_that_cannot_be_written_fails_before_any_point_runs() {
    let d = tmp_dir("unwritable");
    // A file where the folder should be: refused for root too.
    let file = d.join("plain-file");
    std::fs::write(&file, b"x").unwrap();
    let db = d.join("s.db");
    let o = sweep(&db, &["--report", file.join("rep").to_str().unwrap()])
        .output()
        .unwrap();
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("--report: cannot write into"), "{err}");
    assert!(err.contains("fix: give a folder you can write to"), "{err}");
    assert!(!db.exists(), "the database was made before the check");
    assert!(o.stdout.is_empty(), "no answer: no point ran");
    // `sweep report`: the database is named when missing, the folder when unwritable.
    let o = ecsync()
        .args(["sweep", "report", "--db"])
        .arg(d.join("missing.db"))
        .arg("--out")
        .arg(d.join("out"))
        .output()
        .unwrap();
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("--db:") && err.contains("fix:"), "{err}");
    assert!(
        !d.join("out").exists(),
        "the folder was made before the database was checked"
    );
    ok(sweep(&db, &[]));
    let o = ecsync()
        .args(["sweep", "report", "--db"])
        .arg(&db)
        .arg("--out")
        .arg(file.join("out"))
        .output()
        .unwrap();
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("--out: cannot write into"), "{err}");
    std::fs::remove_dir_all(&d).unwrap();
}
