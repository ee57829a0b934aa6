//! What a comparison's report says of its faults, checked against the schedule: lost frames
//! are put down to the kinds of fault the schedule has that lose frames (a delay's late
//! replies), not to kinds it lacks; a step of the master's clock past the run's end says where
//! recording stopped, of how many cycles, and why.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn ecsync() -> Command {
    Command::new(env!("CARGO_BIN_EXE_ecsync"))
}

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("ecsync-fault-words-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// The paper network's cycle, ns, read from its file.
fn paper_cycle_ns() -> u64 {
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../presets/paper-2024.toml"),
    )
    .unwrap();
    let us: u64 = text
        .lines()
        .find_map(|l| l.trim().strip_prefix("cycle_us = "))
        .expect("run.cycle_us")
        .trim()
        .parse()
        .unwrap();
    us * 1000
}

const WARMUP_S: f64 = 12.0;

/// compare on the paper network with `faults` (a schedule's text), one run of median-fit:
/// the output and summary.json.
fn compare(d: &Path, name: &str, faults: &str, cycles: u64) -> (Output, serde_json::Value) {
    let f = d.join(format!("{name}.toml"));
    std::fs::write(&f, faults).unwrap();
    let out = d.join(format!("out-{name}"));
    let o = ecsync()
        .args([
            "compare",
            "--preset",
            "paper-2024",
            "--quiet",
            "--runs",
            "1",
        ])
        .args(["--cycles", &cycles.to_string()])
        .args(["--warmup-s", &WARMUP_S.to_string()])
        .args(["--methods", "median-fit", "--faults"])
        .arg(&f)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let json =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    (o, json)
}

fn warning<'a>(json: &'a serde_json::Value, kind: &str) -> Vec<&'a str> {
    json["warnings"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|w| w["kind"] == kind)
        .map(|w| w["message"].as_str().unwrap())
        .collect()
}

/// A delay longer than the reply timeout (half the cycle) for 50 ms loses the window's frames:
/// as many as the window has cycles; the words name the delay and its size, no power cycle,
/// cable pull or loss. With a power cycle beside it, the power cycle is named, and still no
/// cable pull.
#[test]
fn lost_frames_are_put_down_to_the_schedules_own_faults() {
    let d = tmp("delay");
    let cycle_ns = paper_cycle_ns();
    let extra_us = cycle_ns / 1000 / 2 + 200;
    let (window_s, at_s) = (0.05, WARMUP_S + 1.0);
    let delay = format!(
        "[[fault]]\nat_s = {at_s}\nfor_s = {window_s}\nkind = \"delay\"\nextra_us = {extra_us}\n"
    );
    let (o, json) = compare(&d, "delay", &delay, 2000);
    let lost = json["methods"]["median-fit"]["ground_truth"]["lost_frames"]
        .as_u64()
        .unwrap();
    let window_cycles = (window_s * 1e9 / cycle_ns as f64).round() as u64;
    assert!(
        lost.abs_diff(window_cycles) <= 2,
        "lost {lost}, the window has {window_cycles} cycles"
    );
    let w = warning(&json, "lost_frames");
    assert_eq!(w.len(), 1, "{w:?}");
    assert!(
        w[0].contains(&format!("{lost} of 2000 recorded frames were lost"))
            && w[0].contains(&format!("the fault schedule's delay of {extra_us}.0 us"))
            && w[0].contains("reply timeout"),
        "{}",
        w[0]
    );
    for absent in ["power cycle", "cable pull", "loss"] {
        assert!(!w[0].contains(absent), "{absent}: {}", w[0]);
    }
    // The same words on standard output.
    assert!(
        String::from_utf8_lossy(&o.stdout).contains(w[0]),
        "not in the text"
    );
    // With a power cycle of the first slave beside it.
    let both = format!(
        "{delay}\n[[fault]]\nat_s = {}\nfor_s = 0.2\nkind = \"power_cycle\"\nslave = 1\n",
        at_s + 0.2
    );
    let (_, json) = compare(&d, "both", &both, 2000);
    let w = warning(&json, "lost_frames");
    assert!(
        w.len() == 1
            && w[0].contains("the fault schedule's delay of")
            && w[0].contains("and the cycles its power cycles cut off")
            && !w[0].contains("cable pull"),
        "{w:?}"
    );
}

/// A step of the master's clock 100 s forward, 1 s into the recorded cycles: its task skips
/// the slots the step jumped over, past the run's end. Where recording stopped is the fault's
/// time after the warm-up in cycles; the text and summary.json say it, of how many, and why.
#[test]
fn a_clock_step_past_the_end_says_where_recording_stopped() {
    let d = tmp("step");
    let cycle_ns = paper_cycle_ns();
    let (after_s, step_s, cycles) = (1.0, 100, 5000);
    let (o, json) = compare(
        &d,
        "step",
        &format!(
            "[[fault]]\nat_s = {}\nkind = \"clock_step\"\nstep_us = {}\n",
            WARMUP_S + after_s,
            step_s * 1_000_000
        ),
        cycles,
    );
    let m = &json["methods"]["median-fit"];
    let stops = m["recording_stopped"]
        .as_array()
        .expect("recording_stopped");
    assert_eq!(stops.len(), 1, "{stops:?}");
    let r = &stops[0];
    // The fault plays at the first wake-up at or after its time.
    let expected = (after_s * 1e9 / cycle_ns as f64) as u64;
    let recorded = r["recorded"].as_u64().unwrap();
    assert!(
        (expected..=expected + 3).contains(&recorded),
        "stopped at {recorded}, the step is at cycle {expected}"
    );
    assert_eq!(m["cycles_done"].as_u64().unwrap(), recorded);
    assert_eq!(r["of"].as_u64().unwrap(), cycles);
    let slots = step_s * 1_000_000_000 / cycle_ns;
    let skipped = r["skipped_slots"].as_u64().unwrap();
    assert!(
        (slots - 2..=slots).contains(&skipped),
        "skipped {skipped}, the step is {slots} slots"
    );
    assert_eq!(r["cause"]["kind"], "clock_step");
    assert_eq!(r["cause"]["fault"], 0);
    assert_eq!(
        r["cause"]["step_ns"].as_i64().unwrap(),
        step_s as i64 * 1_000_000_000
    );
    let w = warning(&json, "recording_stopped");
    assert!(
        w.len() == 1
            && w[0].starts_with(&format!(
                "median-fit: recording stopped at cycle {recorded} of {cycles} (run 0): fault[0] (clock_step) stepped the master's clock +{}.000 ms",
                step_s * 1000
            ))
            && w[0].contains(&format!("skipped the {skipped} cycle slots")),
        "{w:?}"
    );
    assert!(
        String::from_utf8_lossy(&o.stdout).contains(w[0]),
        "not in the text"
    );
    // Not taken for a Ctrl-C.
    assert!(warning(&json, "interrupted").is_empty());
}
