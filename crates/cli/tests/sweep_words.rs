//! What a sweep says and stores, checked against what ran: why a method is not ranked (the
//! words `compare` gives for the same scenario), a sweep over the seed, sweeps with points
//! missing, the setting that makes a database another sweep's, options named as options.

mod sweeps;

use rusqlite::Connection;
use std::path::Path;
use sweeps::{SHORT, ecsync, ok, sweep_over};

fn tmp_dir(name: &str) -> std::path::PathBuf {
    sweeps::tmp("ecsync-sweep-words", name)
}

/// One run of 20 000 cycles (enough for a ranking), no warm-up beyond the init frames'.
const RUN: &[&str] = &["--runs", "1", "--cycles", "20000", "--quiet"];

fn sweep(db: &Path, args: &[&str]) -> std::process::Output {
    ok({
        let mut c = ecsync();
        c.arg("sweep").args(args).args(RUN).arg("--db").arg(db);
        c
    })
}

/// `compare --json` on a point's `scenario` (written to `dir/name.toml`): its summary.
fn compare_json(dir: &Path, name: &str, scenario: &str) -> serde_json::Value {
    let cfg = dir.join(format!("{name}.toml"));
    std::fs::write(&cfg, scenario).unwrap();
    let o = ok({
        let mut cmd = ecsync();
        cmd.args(["compare", "--config"])
            .arg(&cfg)
            .args(["--json", "--quiet", "--out"])
            .arg(dir.join(format!("cmp-{name}")));
        cmd
    });
    serde_json::from_slice(&o.stdout).unwrap()
}

/// Runs `ecsync sweep` with `args`, which must fail: its stderr.
fn refused(args: &[&str]) -> String {
    let o = ecsync().arg("sweep").args(args).output().unwrap();
    assert_eq!(o.status.code(), Some(1), "{args:?}");
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// pi-m2s at kp 1.99 goes unstable on paper-2024: the database says why it is not ranked in
/// the words `compare` gives on the point's own scenario, the point's reason ends with them,
/// and the report's row shows them; at kp 0.3 it is ranked and nothing is said.
#[test]
fn why_a_method_is_not_ranked_is_stored_as_compare_words_it() {
    let dir = tmp_dir("unstable");
    let db = dir.join("u.db");
    let report = dir.join("report");
    let grid = ["--grid", "methods.pi-m2s.kp=0.3,1.99"];
    let mut args = grid.to_vec();
    args.extend(["--methods", "pi-m2s,median-fit", "--report"]);
    args.push(report.to_str().unwrap());
    sweep(&db, &args);
    let c = Connection::open(&db).unwrap();
    let (scenario, reason): (String, String) = c
        .query_row(
            "SELECT scenario, reason FROM points WHERE point = 1",
            [],
            |r| Ok((r.get(0)?, r.get(1)?)),
        )
        .unwrap();
    let (rank, why): (Option<i64>, Option<String>) = c
        .query_row(
            "SELECT rank, not_ranked FROM results WHERE point = 1 AND method = 'pi-m2s'",
            [],
            |r| Ok((r.get(0)?, r.get(1)?)),
        )
        .unwrap();
    // compare on the point's scenario: the truth the sweep must agree with.
    let v = compare_json(&dir, "point1", &scenario);
    let nr = v["recommendation"]["not_ranked"].as_array().unwrap();
    assert_eq!(nr.len(), 1, "{nr:?}");
    assert_eq!(nr[0]["method"], "pi-m2s");
    let words = nr[0]["why"].as_str().unwrap();
    assert!(words.contains("went unstable"), "{words}");
    assert!(
        v["methods"]["pi-m2s"]["wild_schedule_cycles"]
            .as_u64()
            .unwrap()
            > 0
    );
    assert_eq!(rank, None);
    assert_eq!(why.as_deref(), Some(words));
    assert!(
        reason.ends_with(&format!("Not ranked: {words}.")),
        "{reason}"
    );
    let html = std::fs::read_to_string(report.join("sweep.html")).unwrap();
    let first = words.split(';').next().unwrap();
    assert!(html.contains(&format!("not ranked: {first}")), "{first}");
    // At kp 0.3 both methods are ranked and nothing is said.
    let said: i64 = c
        .query_row(
            "SELECT count(*) FROM results WHERE point = 0 AND (not_ranked IS NOT NULL OR rank IS NULL)",
            [],
            |r| r.get(0),
        )
        .unwrap();
    assert_eq!(said, 0);
    let r0: String = c
        .query_row("SELECT reason FROM points WHERE point = 0", [], |r| {
            r.get(0)
        })
        .unwrap();
    assert!(!r0.contains("Not ranked"), "{r0}");
}

/// The smallest and largest of a method's column over the points, as the answer prints them.
fn min_max(db: &Path, method: &str, column: &str) -> (f64, f64) {
    Connection::open(db)
        .unwrap()
        .query_row(
            &format!("SELECT min({column}), max({column}) FROM results WHERE method = ?1"),
            [method],
            |r| Ok((r.get(0)?, r.get(1)?)),
        )
        .unwrap()
}

/// Over the seed alone the points ran with different seeds (the database's seed column says
/// so): the answer does not claim one seed, names no winning point, and gives each method's
/// spread over the seeds as SQL finds it; the report marks no point best. Swept with another
/// key, the answer says the best point is partly its seed's luck.
#[test]
fn a_sweep_over_the_seed_reads_its_spread_as_noise() {
    let dir = tmp_dir("seed");
    let db = dir.join("s.db");
    let report = dir.join("report");
    let o = sweep(
        &db,
        &[
            "--grid",
            "run.seed=1:4:1",
            "--methods",
            "median-fit,soem-pi",
            "--report",
            report.to_str().unwrap(),
        ],
    );
    let seeds: i64 = Connection::open(&db)
        .unwrap()
        .query_row("SELECT count(DISTINCT seed) FROM points", [], |r| r.get(0))
        .unwrap();
    assert_eq!(seeds, 4);
    let a = String::from_utf8_lossy(&o.stdout);
    assert!(!a.contains("same seed") && !a.contains("at point"), "{a}");
    assert!(a.starts_with("Answer: no point to pick"), "{a}");
    for m in ["median-fit", "soem-pi"] {
        let (lo, hi) = min_max(&db, m, "smallest_safe_shift_pct");
        let line = a.lines().find(|l| l.trim_start().starts_with(m)).unwrap();
        assert!(
            line.contains(&format!("safe shift {lo:.1} to {hi:.1} %")),
            "{line}"
        );
    }
    // One shard's single point: still a sweep over the seed, no point to pick.
    let o = sweep(
        &dir.join("shard.db"),
        &[
            "--grid",
            "run.seed=1:4:1",
            "--methods",
            "median-fit",
            "--shard",
            "0/4",
        ],
    );
    let one = String::from_utf8_lossy(&o.stdout);
    assert!(one.starts_with("Answer: no point to pick"), "{one}");
    assert!(one.contains("1 seed (1 of the 4 points ran)"), "{one}");
    let t = std::fs::read_to_string(report.join("tradeoff.svg")).unwrap();
    assert!(t.contains("data-best=\"0\"") && !t.contains("data-best=\"1\""));
    let o = sweep(
        &dir.join("s2.db"),
        &[
            "--grid",
            "run.seed=1,2",
            "--grid",
            "run.sync0_shift_pct=20,30",
            "--methods",
            "median-fit",
        ],
    );
    let a = String::from_utf8_lossy(&o.stdout);
    assert!(!a.contains("same seed"), "{a}");
    assert!(
        a.contains("different seeds (run.seed swept)") && a.contains("lucky seed"),
        "{a}"
    );
}

fn points_in(db: &Path) -> (i64, usize) {
    let c = Connection::open(db).unwrap();
    let done = c
        .query_row("SELECT count(*) FROM points", [], |r| r.get(0))
        .unwrap();
    let canonical: String = c
        .query_row("SELECT value FROM sweep WHERE key = 'points'", [], |r| {
            r.get(0)
        })
        .unwrap();
    (done, canonical.lines().count() - 1)
}

/// A shard or a merge with points missing says how many of the sweep's points ran (as the
/// database holds them), one with none says so, and a sweep run whole says nothing of shards
/// and "1 point".
#[test]
fn missing_points_are_counted_as_missing() {
    let dir = tmp_dir("missing");
    let nine = [
        "--grid",
        "run.sync0_shift_pct=10,20,30",
        "--grid",
        "run.target_phase_us=0,10,20",
        "--methods",
        "median-fit",
    ];
    let shard = dir.join("shard0.db");
    let mut args = nine.to_vec();
    args.extend(["--shard", "0/3"]);
    let a = String::from_utf8_lossy(&sweep(&shard, &args).stdout).into_owned();
    let (done, total) = points_in(&shard);
    assert_eq!((done, total), (3, 9));
    assert!(
        a.contains(&format!("({done} of the {total} points ran)")),
        "{a}"
    );
    assert!(
        !a.contains("swept)") && !a.contains("Every point of"),
        "{a}"
    );
    let merged = dir.join("merged.db");
    let o = ecsync()
        .args(["sweep", "merge", "--db"])
        .arg(&merged)
        .arg(&shard)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1));
    let a = String::from_utf8_lossy(&o.stdout);
    assert!(a.contains("(3 of the 9 points ran)"), "{a}");
    // A shard with no point of its own.
    let empty = dir.join("empty.db");
    let mut args = nine.to_vec();
    args.extend(["--shard", "9/10"]);
    let a = String::from_utf8_lossy(&sweep(&empty, &args).stdout).into_owned();
    assert_eq!(points_in(&empty), (0, 9));
    assert_eq!(
        a,
        "Answer: none yet: no point of this sweep has run yet (0 of its 9 points).\n"
    );
    // One point, run whole.
    let one = dir.join("one.db");
    let o = ok(sweep_over(&["--grid", "run.sync0_shift_pct=10"], &one, &[]));
    let a = String::from_utf8_lossy(&o.stdout);
    assert!(a.contains("best point of 1 (1 swept)"), "{a}");
    let o = ok({
        let mut c = ecsync();
        c.args(["sweep", "--grid", "run.sync0_shift_pct=10"])
            .args(SHORT.iter().filter(|a| **a != "--quiet"))
            .arg("--db")
            .arg(&one);
        c
    });
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(
        e.starts_with("ecsync sweep: 1 point over run.sync0_shift_pct, 1 already in"),
        "{e}"
    );
    assert!(!e.contains("shard") && !e.contains("1 points"), "{e}");
}

/// `run.cycles` in the base scenario a database holds (the truth the message must name).
fn cycles_in(db: &Path) -> i64 {
    let toml: String = Connection::open(db)
        .unwrap()
        .query_row("SELECT value FROM sweep WHERE key = 'base_toml'", [], |r| {
            r.get(0)
        })
        .unwrap();
    let t: toml::Table = toml.parse().unwrap();
    t["run"]["cycles"].as_integer().unwrap()
}

/// A database or shard of another sweep is refused naming what differs, with both values as
/// the databases hold them, and the fix.
#[test]
fn another_sweep_is_refused_naming_what_differs() {
    let dir = tmp_dir("another");
    let (c1, c2) = (dir.join("c1.db"), dir.join("c2.db"));
    let grid = [
        "--grid",
        "run.sync0_shift_pct=10",
        "--methods",
        "median-fit",
    ];
    sweep(&c1, &grid);
    let mut args: Vec<&str> = vec!["sweep"];
    args.extend(grid);
    args.extend(["--runs", "1", "--cycles", "30000", "--quiet", "--db"]);
    let mut second = args.clone();
    second.push(c2.to_str().unwrap());
    ok({
        let mut c = ecsync();
        c.args(&second);
        c
    });
    let (n1, n2) = (cycles_in(&c1), cycles_in(&c2));
    assert_eq!((n1, n2), (20000, 30000));
    let mut again = args.clone();
    again.push(c1.to_str().unwrap());
    let e = refused(&again[1..]);
    assert!(
        e.contains(&format!("run.cycles ({n2} here, {n1} in the database)")) && e.contains("fix:"),
        "{e}"
    );
    assert!(e.contains("(1 point over"), "{e}");
    let o = ecsync()
        .args(["sweep", "merge", "--db"])
        .arg(dir.join("m.db"))
        .args([&c1, &c2])
        .output()
        .unwrap();
    let e = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{e}");
    assert!(
        e.contains(&format!(
            "run.cycles ({n2} in {}, {n1} in {})",
            c2.display(),
            c1.display()
        )) && e.contains("fix:"),
        "{e}"
    );
}

/// The numbers of the `<text>` elements of `svg` whose content is a number, as (x, y, value).
fn numbers(svg: &str) -> Vec<(i64, i64, f64)> {
    let attr = |tag: &str, a: &str| -> i64 {
        let at = tag.find(&format!(" {a}=\"")).unwrap() + a.len() + 3;
        tag[at..].split('"').next().unwrap().parse().unwrap()
    };
    svg.split("<text")
        .skip(1)
        .filter_map(|t| {
            let (tag, rest) = t.split_once('>')?;
            let v: f64 = rest.split('<').next()?.trim().parse().ok()?;
            Some((attr(tag, "x"), attr(tag, "y"), v))
        })
        .collect()
}

/// The caption of tradeoff.svg in sweep.html says where the phase-error axis starts, and the
/// drawing agrees: the value at the plot's bottom edge, read off its tick labels, is the
/// caption's (to a pixel), and neither is 0.
#[test]
fn the_trade_off_caption_says_where_its_axis_starts() {
    let dir = tmp_dir("axis");
    let report = dir.join("report");
    sweep(
        &dir.join("a.db"),
        &[
            "--grid",
            "run.target_phase_us=0,10",
            "--methods",
            "median-fit,soem-pi",
            "--report",
            report.to_str().unwrap(),
        ],
    );
    let html = std::fs::read_to_string(report.join("sweep.html")).unwrap();
    assert!(!html.contains("(from 0)"));
    let key = "up, its phase error p99.9 (linear from ";
    let at = html.find(key).expect("the caption's axis") + key.len();
    let words: Vec<&str> = html[at..].split(' ').collect();
    let (lo, hi): (f64, f64) = (words[0].parse().unwrap(), words[2].parse().unwrap());
    let svg = std::fs::read_to_string(report.join("tradeoff.svg")).unwrap();
    // The y ticks: numbers in one column, one above the other.
    let nums = numbers(&svg);
    let ticks: Vec<(i64, f64)> = nums
        .iter()
        .filter(|(x, _, _)| nums.iter().filter(|n| n.0 == *x).count() > 2)
        .map(|(_, y, v)| (*y, *v))
        .collect();
    assert!(ticks.len() >= 2, "{nums:?}");
    let ((y1, v1), (y2, v2)) = (ticks[0], ticks[ticks.len() - 1]);
    let per_px = (v2 - v1) / (y2 - y1) as f64;
    // The plot's bottom: where its vertical grid lines start.
    let line = svg
        .split("<line")
        .skip(1)
        .find(|l| {
            let x = |a: &str| {
                l.split(&format!(" {a}=\""))
                    .nth(1)
                    .unwrap()
                    .split('"')
                    .next()
                    .unwrap()
                    .to_string()
            };
            x("x1") == x("x2")
        })
        .unwrap();
    let y_of = |a: &str| -> i64 {
        line.split(&format!(" {a}=\""))
            .nth(1)
            .unwrap()
            .split('"')
            .next()
            .unwrap()
            .parse()
            .unwrap()
    };
    let bottom = y_of("y1").max(y_of("y2"));
    let drawn_lo = v1 + (bottom - y1) as f64 * per_px;
    assert!(lo > 0.0 && lo < hi, "{lo} {hi}");
    assert!(
        (drawn_lo - lo).abs() <= 2.0 * per_px.abs(),
        "drawn from {drawn_lo}, caption {lo}"
    );
}

/// `scripts/recipes/sweep-parallel.sh` run again in the same folder keeps the shards it made:
/// each goes on where it stopped (its log's second row ran no point), and the merge is the
/// same. (GNU parallel: the script installs it when missing; CI has it.)
#[test]
fn the_parallel_recipe_run_again_keeps_its_shards() {
    let dir = tmp_dir("recipe");
    let script =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scripts/recipes/sweep-parallel.sh");
    let out = dir.join("out");
    let run = || {
        let o = std::process::Command::new("bash")
            .arg(&script)
            .arg("2")
            .arg(&out)
            .args(["--grid", "run.sync0_shift_pct=10,20,30,40"])
            .args(RUN)
            .args(["--methods", "median-fit", "--threads", "1"])
            .env("ECSYNC_BIN", env!("CARGO_BIN_EXE_ecsync"))
            .output()
            .unwrap();
        assert!(
            o.status.success(),
            "{}{}",
            String::from_utf8_lossy(&o.stdout),
            String::from_utf8_lossy(&o.stderr)
        );
    };
    let log = |db: &Path| -> Vec<i64> {
        let c = Connection::open(db).unwrap();
        let mut q = c
            .prepare("SELECT points_run FROM log ORDER BY invocation")
            .unwrap();
        q.query_map([], |r| r.get(0))
            .unwrap()
            .map(Result::unwrap)
            .collect()
    };
    run();
    assert_eq!(points_in(&out.join("merged.db")), (4, 4));
    run();
    for i in 0..2 {
        assert_eq!(log(&out.join(format!("shard-{i}.db"))), [2, 0], "shard {i}");
    }
    assert_eq!(points_in(&out.join("merged.db")), (4, 4));
}

/// Values set by options are refused naming the option, not a point or a line of a text the
/// sweep made; a range past the most points a sweep takes says how many it asked and the most.
#[test]
fn options_and_ranges_are_refused_naming_them() {
    let dir = tmp_dir("options");
    let db = dir.join("o.db");
    let grid = ["--grid", "run.sync0_shift_pct=10,20"];
    for (opt, value) in [("--runs", "0"), ("--cycles", "0"), ("--methods", "nosuch")] {
        let mut args = grid.to_vec();
        args.extend([opt, value, "--db", db.to_str().unwrap()]);
        let e = refused(&args);
        assert!(e.contains(&format!("error: {opt}: ")), "{e}");
        assert!(
            e.contains("fix:") && !e.contains("point") && !e.contains(":4"),
            "{e}"
        );
    }
    let e = refused(&["--grid", "run.seed=0:1e9:1", "--db", db.to_str().unwrap()]);
    assert!(
        e.contains("1000000001 values") && e.contains("more than the 1000000 points"),
        "{e}"
    );
    assert!(!db.exists(), "nothing made");
}

/// A sweep over the cycle time names the shortest cycle each method held, and says why the
/// answer leans to the longest (each shift is a share of its own point's cycle); checked with
/// `compare` at that cycle (no late or lost frame, on target) and at the one below it in the
/// sweep (late frames). Before, it named the 1000 us point best and said nothing else.
#[test]
fn a_sweep_over_the_cycle_names_the_shortest_cycle_held() {
    let dir = tmp_dir("cycle");
    let db = dir.join("c.db");
    let o = sweep(
        &db,
        &[
            "--grid",
            "run.cycle_us=250,300,1000",
            "--methods",
            "median-fit",
            "--warmup-s",
            "10",
        ],
    );
    let a = String::from_utf8_lossy(&o.stdout).into_owned();
    assert!(
        a.starts_with("Answer: median-fit at point 2 (run.cycle_us=1000)"),
        "{a}"
    );
    assert!(
        a.contains("so the answer leans to the longest. The shortest cycle each method held (no late or lost frame, on target): median-fit 300 us (point 1)."),
        "{a}"
    );
    let truth = |cycle: &str| -> serde_json::Value {
        let o = ok({
            let mut c = ecsync();
            c.args(["compare", "--methods", "median-fit", "--cycle-us", cycle])
                .args(["--warmup-s", "10", "--json", "--out"])
                .arg(dir.join(format!("cmp-{cycle}")))
                .args(RUN);
            c
        });
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        v["methods"]["median-fit"]["ground_truth"].clone()
    };
    let at = truth("300");
    assert_eq!(at["late_frames"], 0, "{at}");
    assert_eq!(at["lost_frames"], 0, "{at}");
    assert_eq!(at["holds_target"], true, "{at}");
    let below = truth("250");
    assert!(below["late_frames"].as_u64().unwrap() > 0, "{below}");
}

/// A `--list` written by a CSV writer (Python's csv module writes a list of send modes as
/// `"[""plain"", ""spin""]"`) gives the points a `--grid` of the same values gives: the same
/// scenario at every point. Before, the CSV quotes were kept and the cell read as a string
/// ("invalid type: string ..., expected a sequence"), though the list's doc promised CSV
/// quoting.
#[test]
fn a_list_quoted_as_csv_quotes_is_read_as_the_grid() {
    let dir = tmp_dir("csv");
    let list = dir.join("points.csv");
    std::fs::write(
        &list,
        "send.modes,methods.median-fit.gain\n\"[\"\"plain\"\", \"\"spin\"\"]\",0.02\n\"[\"\"plain\"\"]\",\"0.005\"\n",
    )
    .unwrap();
    let args = ["--methods", "median-fit", "--warmup-s", "10"];
    let mut with_list = args.to_vec();
    with_list.extend(["--list", list.to_str().unwrap()]);
    sweep(&dir.join("list.db"), &with_list);
    let scenarios = |db: &Path| -> Vec<String> {
        let c = Connection::open(db).unwrap();
        let mut st = c
            .prepare("SELECT scenario FROM points ORDER BY point")
            .unwrap();
        st.query_map([], |r| r.get(0))
            .unwrap()
            .map(Result::unwrap)
            .collect()
    };
    for (i, (modes, gain)) in [(r#"["plain", "spin"]"#, "0.02"), (r#"["plain"]"#, "0.005")]
        .into_iter()
        .enumerate()
    {
        let db = dir.join(format!("grid{i}.db"));
        let mut with_grid = args.to_vec();
        let (m, g) = (
            format!("send.modes={modes}"),
            format!("methods.median-fit.gain={gain}"),
        );
        with_grid.extend(["--grid", m.as_str(), "--grid", g.as_str()]);
        sweep(&db, &with_grid);
        assert_eq!(
            scenarios(&dir.join("list.db"))[i],
            scenarios(&db)[0],
            "point {i}"
        );
    }
    let c = Connection::open(dir.join("list.db")).unwrap();
    let spin: i64 = c
        .query_row(
            "SELECT count(*) FROM results WHERE point = 0 AND method = 'median-fit+spin'",
            [],
            |r| r.get(0),
        )
        .unwrap();
    assert_eq!(spin, 1);
}

/// A method with no good point is told why, counted over its points: snap on paper-2024 sits
/// off its target (12 % of the margin, over compare's 10 %) with no late or lost frame, and the
/// answer says so, as `compare` finds at each point. Before, it said only "no point without
/// late or lost frames on target", which reads as if it had late frames.
#[test]
fn a_method_without_a_good_point_is_told_why() {
    let dir = tmp_dir("why");
    let db = dir.join("w.db");
    let o = sweep(
        &db,
        &[
            "--grid",
            "run.target_phase_us=0,10",
            "--methods",
            "snap,median-fit",
            "--warmup-s",
            "10",
        ],
    );
    let a = String::from_utf8_lossy(&o.stdout).into_owned();
    assert!(
        a.contains("  snap        no point without late or lost frames on target (off its target at 2 of its 2 points)\n"),
        "{a}"
    );
    for phase in ["0", "10"] {
        let o = ok({
            let mut c = ecsync();
            c.args(["compare", "--methods", "snap,median-fit"])
                .args([
                    "--target-phase-us",
                    phase,
                    "--warmup-s",
                    "10",
                    "--json",
                    "--out",
                ])
                .arg(dir.join(format!("cmp-{phase}")))
                .args(RUN);
            c
        });
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        let g = &v["methods"]["snap"]["ground_truth"];
        assert_eq!(g["holds_target"], false, "{g}");
        assert_eq!(
            (&g["late_frames"], &g["lost_frames"]),
            (&0.into(), &0.into()),
            "{g}"
        );
        let ranking = v["recommendation"]["ranking"].as_array().unwrap();
        assert!(ranking.contains(&"snap".into()), "{ranking:?}");
    }
}

/// dcm-master-shift at kp 0.0005 pulls in slowly: after a 10 s warm-up `compare` on the
/// point's scenario warns that it was still settling (it reports in sync during the recording,
/// and is ranked; at kp 0.0003 it never does within it, and is not ranked). The sweep stores that warning with the
/// method's results and its answer, which names that point (the only one), says so; at the
/// letter's kp 0.004 compare does not warn, and neither does the sweep. Before, the answer
/// named a settling point as if its figures were where the method settles.
#[test]
fn the_answer_says_when_its_point_was_still_settling() {
    let dir = tmp_dir("settling");
    for (kp, settles_late) in [("0.0005", true), ("0.004", false)] {
        let db = dir.join(format!("kp{kp}.db"));
        let grid = format!("methods.dcm-master-shift.kp={kp}");
        let out = sweep(
            &db,
            &[
                "--grid",
                &grid,
                "--methods",
                "dcm-master-shift",
                "--warmup-s",
                "10",
            ],
        );
        let text = String::from_utf8_lossy(&out.stdout).into_owned();
        let c = Connection::open(&db).unwrap();
        let (scenario, kinds): (String, String) = c
            .query_row(
                "SELECT p.scenario, r.warnings FROM points p JOIN results r USING (point)
                 WHERE point = 0 AND method = 'dcm-master-shift'",
                [],
                |r| Ok((r.get(0)?, r.get(1)?)),
            )
            .unwrap();
        // compare on the point's scenario: the truth the sweep must agree with.
        let v = compare_json(&dir, &format!("kp{kp}"), &scenario);
        let warned = v["warnings"]
            .as_array()
            .unwrap()
            .iter()
            .any(|w| w["kind"] == "settling" && w["method"] == "dcm-master-shift");
        assert_eq!(warned, settles_late, "kp {kp}: {}", v["warnings"]);
        assert_eq!(
            kinds.split(", ").any(|k| k == "settling"),
            warned,
            "{kinds}"
        );
        assert!(
            text.starts_with("Answer: dcm-master-shift at point 0 "),
            "{text}"
        );
        assert_eq!(
            text.contains(
                "  Warning: dcm-master-shift was still settling at point 0 when the recording began"
            ),
            warned,
            "kp {kp}: {text}"
        );
        assert_eq!(
            text.contains("; still settling as the recording began"),
            warned,
            "{text}"
        );
    }
}
