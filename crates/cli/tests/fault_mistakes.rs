//! A fault schedule's mistakes as a new user makes them, in every command that reads one
//! (compare, bringup, serve, tsn run): a slave or a port the network lacks is refused naming the file,
//! the entry, its line, the field and the fix, before anything runs or is written; a fault past
//! the run's end and an empty schedule are told; a missing field or a bad value says what to
//! write.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn ecsync() -> Command {
    Command::new(env!("CARGO_BIN_EXE_ecsync"))
}

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!(
        "ecsync-fault-mistakes-{}-{name}",
        std::process::id()
    ));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn write(dir: &Path, name: &str, text: &str) -> String {
    let f = dir.join(name);
    std::fs::write(&f, text).unwrap();
    f.to_str().unwrap().to_string()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).to_string()
}

/// The paper network's slaves, counted in its file (the truth the check must agree with).
fn paper_slaves() -> usize {
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../presets/paper-2024.toml"),
    )
    .unwrap();
    text.lines()
        .filter(|l| l.trim() == "[[segment.slave]]")
        .count()
}

fn short_compare(faults: &str, out: &Path) -> Output {
    ecsync()
        .args([
            "compare",
            "--preset",
            "paper-2024",
            "--quiet",
            "--runs",
            "1",
            "--cycles",
            "2000",
            "--warmup-s",
            "12",
            "--methods",
            "median-fit",
            "--faults",
            faults,
            "--out",
        ])
        .arg(out)
        .output()
        .unwrap()
}

/// A slave past the network's end, for every kind that names one, and a port without a cable:
/// refused by compare, bringup and serve alike, nothing written; the slave just inside the
/// network is accepted.
#[test]
fn a_slave_or_port_the_network_lacks_is_refused_everywhere() {
    let d = tmp("slave");
    let n = paper_slaves();
    assert!(n >= 2, "the preset's slaves: {n}");
    for (kind, extra) in [
        ("power_cycle", "for_s = 0.2\n"),
        ("al_error", ""),
        ("link_down", "for_s = 0.05\n"),
    ] {
        let f = write(
            &d,
            &format!("{kind}.toml"),
            &format!(
                "# past the end\n\n[[fault]]\nat_s = 13\n{extra}kind = \"{kind}\"\nslave = {}\n",
                n + 3
            ),
        );
        let out = d.join(format!("out-{kind}"));
        let pcap = d.join(format!("{kind}.pcap"));
        let runs = [
            short_compare(&f, &out),
            ecsync()
                .args([
                    "bringup",
                    "--preset",
                    "paper-2024",
                    "--faults",
                    &f,
                    "--pcap",
                ])
                .arg(&pcap)
                .output()
                .unwrap(),
            ecsync()
                .args([
                    "serve",
                    "--iface",
                    "ecsync-no-such-if",
                    "--preset",
                    "paper-2024",
                    "--faults",
                    &f,
                ])
                .output()
                .unwrap(),
        ];
        for o in &runs {
            let e = stderr(o);
            assert!(!o.status.success(), "{kind}: accepted: {e}");
            assert!(
                e.contains(&format!(
                    "{kind}.toml:3: fault[0].slave: slave {} is not in the network",
                    n + 3
                )) && e.contains(&format!("has {n} slaves"))
                    && e.contains(&format!("fix: give a network position from 1 to {n}")),
                "{kind}: {e}"
            );
        }
        assert!(
            !out.exists() && !pcap.exists(),
            "{kind}: something was written"
        );
    }
    last_slave_port_and_itself(&d, n, "paper-2024", 13.0, short_compare);
}

/// The last of the `n` slaves of `network` has no cable behind it (port 1): a link_down
/// there is refused naming the port (`run` with a schedule file and an output folder), and
/// a power cycle of the last slave itself runs; the faults at `at_s`.
fn last_slave_port_and_itself(
    d: &Path,
    n: usize,
    network: &str,
    at_s: f64,
    run: impl Fn(&str, &Path) -> Output,
) {
    let f = write(
        d,
        "port.toml",
        &format!(
            "[[fault]]\nat_s = {at_s}\nfor_s = 0.05\nkind = \"link_down\"\nslave = {n}\nport = 1\n"
        ),
    );
    let e = stderr(&run(&f, &d.join("out-port")));
    assert!(
        e.contains("port.toml:1: fault[0].port")
            && e.contains(&format!(
                "slave {n} of preset {network} has no cable at port 1"
            )),
        "{e}"
    );
    let f = write(
        d,
        "last.toml",
        &format!("[[fault]]\nat_s = {at_s}\nfor_s = 0.05\nkind = \"power_cycle\"\nslave = {n}\n"),
    );
    let o = run(&f, &d.join("out-last"));
    assert!(o.status.success(), "{}", stderr(&o));
}

/// A fault that starts after the run's end (12 s of warm-up and 2000 cycles of 1 ms: 14 s) is
/// told before the run, with its line and how to fix it; one inside is not; an empty schedule
/// is told.
#[test]
fn a_fault_past_the_end_and_an_empty_schedule_are_told() {
    let d = tmp("late");
    let f = write(
        &d,
        "late.toml",
        "[[fault]]\nat_s = 13.9\nkind = \"loss\"\nframes = 3\n\n[[fault]]\nat_s = 500\nfor_s = 0.2\nkind = \"power_cycle\"\nslave = 2\n",
    );
    let o = short_compare(&f, &d.join("out"));
    let e = stderr(&o);
    assert!(o.status.success(), "{e}");
    assert!(
        e.contains("late.toml:6: fault[1].at_s: the power_cycle fault at 500 s starts after the run's end, 14 s after the start of the cyclic phase: it is never played; fix: give at_s below 14 or run longer"),
        "{e}"
    );
    assert!(!e.contains("fault[0]"), "{e}");
    // The first is played, the second not: the run's own events say so.
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("out/summary.json")).unwrap())
            .unwrap();
    let not_played: Vec<&str> = json["warnings"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|w| w["kind"] == "fault_not_played")
        .map(|w| w["message"].as_str().unwrap())
        .collect();
    assert!(
        not_played.len() == 1
            && not_played[0].starts_with("fault[1] (power_cycle at 500 s) started in no run"),
        "{not_played:?}"
    );
    let text = json.to_string();
    assert!(
        text.contains("\"fault\":0") && !text.contains("\"fault\":1"),
        "the events: {text}"
    );
    let f = write(&d, "empty.toml", "# no faults yet\nseed = 4\n");
    for o in [
        short_compare(&f, &d.join("out-empty")),
        ecsync()
            .args(["bringup", "--preset", "paper-2024", "--faults", &f])
            .output()
            .unwrap(),
    ] {
        let e = stderr(&o);
        assert!(o.status.success(), "{e}");
        assert!(
            e.contains("empty.toml: no [[fault]] entry: the run plays no fault"),
            "{e}"
        );
    }
}

/// A missing `kind` points at files that have faults; a bad epoch lists the accepted values.
#[test]
fn a_missing_field_or_a_bad_value_says_what_to_write() {
    let d = tmp("fields");
    let f = write(&d, "nokind.toml", "[[fault]]\nat_s = 15\n");
    let e = stderr(&short_compare(&f, &d.join("out")));
    assert!(
        e.contains("nokind.toml:1: fault[0].kind: missing field `kind`")
            && e.contains("presets/faults-demo.toml")
            && !e.contains("paper-2024.toml"),
        "{e}"
    );
    let f = write(
        &d,
        "epoch.toml",
        "epoch = \"begin\"\n[[fault]]\nat_s = 1\nkind = \"loss\"\nframes = 1\n",
    );
    let e = stderr(&short_compare(&f, &d.join("out")));
    assert!(
        e.contains("epoch.toml:1: epoch: unknown variant `begin`")
            && e.contains("fix: give one of the accepted values: `cyclic` or `start`"),
        "{e}"
    );
    // A misspelt field names its entry as the other mistakes do (it said `typo.toml:8:
    // probabilty: unknown field`, the entry left to find).
    let f = write(
        &d,
        "typo.toml",
        "[[fault]]\nat_s = 1\nkind = \"loss\"\nframes = 1\n\n[[fault]]\nat_s = 2\nprobabilty = 0.1\nkind = \"loss\"\n",
    );
    let e = stderr(&short_compare(&f, &d.join("out")));
    assert!(
        e.contains("typo.toml:8: fault[1].probabilty: unknown field `probabilty`")
            && e.contains("fix: remove the field or correct its spelling"),
        "{e}"
    );
    assert!(!d.join("out").exists());
}

/// `bringup --faults` says what the faults did: the frames the schedule dropped (the player's
/// count) are the frames the master sent again (its exchanges' count) when it gave up on none;
/// the fault events during the bring-up, and the faults it did not reach.
#[test]
fn bringup_says_what_the_faults_did() {
    let d = tmp("bringup");
    let f = write(
        &d,
        "b.toml",
        "epoch = \"start\"\n[[fault]]\nat_s = 0\nkind = \"loss\"\nprobability = 0.05\n\n[[fault]]\nat_s = 1.0\nfor_s = 0.01\nkind = \"corrupt\"\nprobability = 0.5\n\n[[fault]]\nat_s = 100\nkind = \"host_stall\"\nstall_ms = 1\n",
    );
    let o = ecsync()
        .args([
            "bringup",
            "--preset",
            "paper-2024",
            "--json",
            "--faults",
            &f,
        ])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let x = &v["faults"];
    let c = &x["counts"];
    let dropped = c["lost_out"].as_u64().unwrap() + c["lost_back"].as_u64().unwrap();
    assert!(dropped > 10 && c["corrupted"].as_u64().unwrap() > 0, "{x}");
    assert_eq!(x["given_up"], 0, "{x}");
    assert_eq!(x["retries"].as_u64().unwrap(), dropped, "{x}");
    let events: Vec<(u64, String)> = x["events"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| {
            (
                e["fault"].as_u64().unwrap(),
                e["edge"].as_str().unwrap().to_string(),
            )
        })
        .collect();
    assert_eq!(
        events,
        [(0, "start".into()), (1, "start".into()), (1, "end".into())],
        "{x}"
    );
    assert_eq!(x["not_reached"][0]["fault"], 2, "{x}");
    // The same in words.
    let o = ecsync()
        .args(["bringup", "--preset", "paper-2024", "--faults", &f])
        .output()
        .unwrap();
    let so = String::from_utf8_lossy(&o.stdout);
    assert!(
        so.contains(&format!("the schedule dropped {dropped} frames"))
            && so.contains(&format!("the bring-up sent {dropped} frames again"))
            && so.contains("fault[1] corrupt end")
            && so.contains("not reached (the bring-up ended")
            && so.contains("fault[2] host_stall at 100 s"),
        "{so}"
    );
    // Without --faults: no such line, no such field.
    let o = ecsync()
        .args(["bringup", "--preset", "paper-2024", "--json"])
        .output()
        .unwrap();
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert!(v.get("faults").is_none());
}

/// `tsn run --faults` checks the schedule against the network as compare does: a slave past
/// the end and a port without a cable are refused before any variant runs, naming the file,
/// the entry's line, the field and the fix, nothing written; the last slave is accepted. The
/// preset tsn-2020 has no [segment] table: its network is paper-2024's, counted in that file.
#[test]
fn tsn_run_refuses_a_slave_or_port_the_network_lacks() {
    let d = tmp("tsn");
    let tsn = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../presets/tsn-2020.toml"),
    )
    .unwrap();
    assert!(
        !tsn.lines().any(|l| l.trim_start().starts_with("[segment")),
        "tsn-2020 has a segment of its own"
    );
    let n = paper_slaves();
    let tsn_run = |faults: &str, out: &Path| {
        ecsync()
            .args([
                "tsn",
                "run",
                "--variants",
                "M1",
                "--duration-s",
                "0.2",
                "--faults",
                faults,
                "--out",
            ])
            .arg(out)
            .output()
            .unwrap()
    };
    let f = write(
        &d,
        "slave.toml",
        &format!(
            "# past the end\n\n[[fault]]\nat_s = 10.1\nfor_s = 0.05\nkind = \"power_cycle\"\nslave = {}\n",
            n + 3
        ),
    );
    let out = d.join("out-slave");
    let o = tsn_run(&f, &out);
    let e = stderr(&o);
    assert!(!o.status.success(), "accepted: {e}");
    assert!(
        e.contains(&format!(
            "slave.toml:3: fault[0].slave: slave {} is not in the network: preset tsn-2020 has {n} slaves",
            n + 3
        )) && e.contains(&format!("fix: give a network position from 1 to {n}")),
        "{e}"
    );
    assert!(!e.contains("running M1"), "it ran: {e}");
    assert!(!out.exists(), "something was written");
    last_slave_port_and_itself(&d, n, "tsn-2020", 10.1, tsn_run);
}
