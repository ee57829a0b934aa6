//! Issue 30, edge 7: the main job's command line and configuration as a new user meets them:
//! `--cycle-us` and `--master-ppm` (the master's crystal out of the host preset's shadow), a
//! file that is not UTF-8 named by line, a segment without slaves and a fault entry without its
//! value each refused with the fix, progress lines when stderr is not a terminal.

use std::path::PathBuf;
use std::process::{Command, Output};

fn ecsync() -> Command {
    Command::new(env!("CARGO_BIN_EXE_ecsync"))
}

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("ecsync-edges-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn run(args: &[&str]) -> Output {
    ecsync().args(args).output().unwrap()
}

fn text(o: &Output) -> (String, String) {
    (
        String::from_utf8_lossy(&o.stdout).to_string(),
        String::from_utf8_lossy(&o.stderr).to_string(),
    )
}

/// `--cycle-us 250` runs the preset at a 250 us cycle with the warm-up's seconds kept (12 s:
/// 48 000 cycles), and `--master-ppm` sets the master's crystal the header then shows;
/// summary.json holds both.
#[test]
fn cycle_and_master_crystal_from_the_command_line() {
    let out = tmp("cycle");
    let o = run(&[
        "compare",
        "--quiet",
        "--methods",
        "median-fit",
        "--runs",
        "1",
        "--cycles",
        "2000",
        "--warmup-s",
        "12",
        "--cycle-us",
        "250",
        "--master-ppm",
        "-20",
        "--out",
        out.to_str().unwrap(),
    ]);
    let (so, se) = text(&o);
    assert!(o.status.success(), "{se}");
    assert!(
        so.contains("master crystal -20.0 ppm") && so.contains("cycle 250 us"),
        "{so}"
    );
    assert!(so.contains("after 48000 warm-up cycles"), "{so}");
    let j: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    assert_eq!(j["cycle_ns"], 250_000);
    assert_eq!(j["master_ppm"], -20.0);
    // Out of range, each names its flag and the fix.
    let (_, e) = text(&run(&["compare", "--quiet", "--cycle-us", "0.5"]));
    assert!(
        e.contains("--cycle-us: a cycle of 0.5 us is not an EtherCAT cycle") && e.contains("fix:"),
        "{e}"
    );
    let (_, e) = text(&run(&["compare", "--quiet", "--master-ppm", "900"]));
    assert!(
        e.contains("--master-ppm: 900 ppm") && e.contains("fix:"),
        "{e}"
    );
}

/// A Latin-1 "é" in a comment on line 3: refused naming line 3, column 6 and the byte.
#[test]
fn a_file_that_is_not_utf8_is_refused_by_line() {
    let d = tmp("utf8");
    let f = d.join("latin1.toml");
    std::fs::write(
        &f,
        b"[segment]\nseed = 1\n# caf\xe9\n[[segment.slave]]\nname = \"a\"\nupstream = \"master\"\n",
    )
    .unwrap();
    for cmd in ["compare", "bringup"] {
        let o = run(&[cmd, "--config", f.to_str().unwrap()]);
        let (_, e) = text(&o);
        assert!(!o.status.success());
        assert!(
            e.contains("latin1.toml:3:") && e.contains("byte 0xE9 at column 6 is not UTF-8"),
            "{cmd}: {e}"
        );
        assert!(e.contains("fix: save the file as UTF-8"), "{e}");
    }
    // The fault schedule is read the same way.
    let o = run(&["compare", "--quiet", "--faults", f.to_str().unwrap()]);
    let (_, e) = text(&o);
    assert!(e.contains("latin1.toml:3:"), "{e}");
}

/// No `[[segment.slave]]` (or no `[segment]` at all): "the segment has no slaves" and how to
/// add one, not serde's "missing field `slave`"; a slave without a name names the field.
#[test]
fn a_segment_without_slaves_says_what_to_add() {
    let d = tmp("noslave");
    for (name, body) in [
        (
            "noslave.toml",
            "[segment]\nseed = 1\n[run]\ncycle_us = 1000\n",
        ),
        ("noseg.toml", "[run]\ncycle_us = 1000\n"),
    ] {
        let f = d.join(name);
        std::fs::write(&f, body).unwrap();
        let (_, e) = text(&run(&["compare", "--config", f.to_str().unwrap()]));
        assert!(
            e.contains("the segment has no slaves")
                && e.contains("add at least one [[segment.slave]] table"),
            "{name}: {e}"
        );
        assert!(!e.contains("missing field"), "{e}");
    }
    let f = d.join("noname.toml");
    std::fs::write(
        &f,
        "[segment]\n[[segment.slave]]\nmodel = \"servo-mii\"\nupstream = \"master\"\n",
    )
    .unwrap();
    let (_, e) = text(&run(&["compare", "--config", f.to_str().unwrap()]));
    assert!(
        e.contains(":2:") && e.contains("add the field `name`"),
        "{e}"
    );
}

/// A fault entry without the value its kind needs names the key, not "NaN is out of range".
#[test]
fn a_fault_without_its_value_names_the_key() {
    let d = tmp("faults");
    for (kind, key) in [
        ("host_stall", "stall_ms"),
        ("delay", "extra_us"),
        ("clock_step", "step_us"),
    ] {
        let f = d.join(format!("{kind}.toml"));
        std::fs::write(&f, format!("[[fault]]\nat_s = 1\nkind = \"{kind}\"\n")).unwrap();
        let (_, e) = text(&run(&[
            "compare",
            "--quiet",
            "--faults",
            f.to_str().unwrap(),
        ]));
        assert!(
            e.contains(&format!("kind \"{kind}\" needs {key}"))
                && e.contains(&format!("add {key} = ")),
            "{e}"
        );
        assert!(!e.contains("NaN"), "{e}");
    }
}

/// stderr not a terminal (a pipe here): progress comes as lines, the bring-up's first.
#[test]
fn progress_lines_when_stderr_is_a_pipe() {
    let out = tmp("lines");
    let o = run(&[
        "compare",
        "--methods",
        "median-fit",
        "--runs",
        "1",
        "--cycles",
        "2000",
        "--warmup-s",
        "12",
        "--out",
        out.to_str().unwrap(),
    ]);
    let (_, e) = text(&o);
    assert!(o.status.success(), "{e}");
    let first = e.lines().next().unwrap_or_default();
    assert!(
        first.starts_with("ecsync: 0 s, bring-up: "),
        "the first progress line: {e}"
    );
    // No bar's control characters in a log.
    assert!(!e.contains('\r') && !e.contains('\u{1b}'), "{e:?}");
    // --quiet: none.
    let o = run(&[
        "compare",
        "--quiet",
        "--methods",
        "median-fit",
        "--runs",
        "1",
        "--cycles",
        "2000",
        "--warmup-s",
        "12",
        "--out",
        out.to_str().unwrap(),
    ]);
    let (_, e) = text(&o);
    assert!(!e.contains("bring-up:"), "{e}");
}

/// `tsn run`'s report.html holds its plots as inline SVG, as compare's does: the file alone
/// shows them.
#[test]
fn the_tsn_report_is_self_contained() {
    let out = tmp("tsn");
    let o = run(&["tsn", "run", "--out", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", text(&o).1);
    let html = std::fs::read_to_string(out.join("report.html")).unwrap();
    let figures = html.matches("<svg").count();
    assert!(figures >= 3, "{figures} inline figures");
    assert!(
        !html.contains("<img") && !html.contains("src=\""),
        "a linked plot"
    );
    // The SVG files are still written beside it.
    assert!(out.join("tsn_histograms.svg").exists() && out.join("tsn_histograms.png").exists());
}
