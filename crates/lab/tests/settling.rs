//! A method still settling when the recording begins is named, with the warm-up that leaves
//! its start out: median-fit's init ends as a warm-up of exactly the init's 10 s does, and it
//! pulls in from where its init frames left the phase at the letter's gain of 0.01.

use ecsync_lab::report::summarize;
use ecsync_lab::scenario::Scenario;
use std::sync::atomic::AtomicU64;

/// The lan9252-pair preset (crystals 8.4 ppm apart) with median-fit and bus-shift after a
/// warm-up of `warmup_s`.
fn lan9252_pair(warmup_s: u64) -> Scenario {
    let text = ecsync_sim::preset::named("lan9252-pair").expect("the preset");
    let mut s = ecsync_lab::parse("lan9252-pair.toml", text).expect("the preset parses");
    s.methods = ["median-fit", "bus-shift"]
        .map(|m| m.parse().expect("a method"))
        .to_vec();
    s.warmup_cycles = warmup_s * 1_000_000_000 / u64::from(s.cycle_ns);
    s
}

#[test]
fn a_method_still_settling_as_the_recording_begins_is_named_with_the_warm_up_that_ends_it() {
    let c = ecsync_lab::compare(&lan9252_pair(10), 2, &AtomicU64::new(0)).expect("runs");
    // The ground truth of the first block of cycles: median-fit's frames reach the reference
    // far from the target (its init left them there), bus-shift's do not.
    let first_max = |m: usize| f64::from(c.results[m][0].series[2][0].max);
    assert!(first_max(0) > 60_000.0, "median-fit {}", first_max(0));
    assert!(first_max(1) < 60_000.0, "bus-shift {}", first_max(1));
    let out = summarize(&c);
    let settling: Vec<_> = out
        .warnings
        .iter()
        .filter(|w| w.kind == "settling")
        .collect();
    assert_eq!(settling.len(), 1, "{:?}", out.warnings);
    let w = settling[0];
    assert_eq!(w.method.as_deref(), Some("median-fit"));
    assert!(
        w.message.contains("a warm-up 1 s longer") && w.message.contains("now 10 s"),
        "{}",
        w.message
    );

    // With the warm-up it names: no warning, and the start no longer sets median-fit's max
    // and its smallest safe shift.
    let c = ecsync_lab::compare(&lan9252_pair(11), 2, &AtomicU64::new(0)).expect("runs");
    let settled = summarize(&c);
    assert!(
        settled.warnings.iter().all(|w| w.kind != "settling"),
        "{:?}",
        settled.warnings
    );
    let g = |o: &ecsync_lab::report::SummaryOut| o.methods["median-fit"].ground_truth.clone();
    let (before, after) = (g(&out), g(&settled));
    assert!(
        after.phase.max < before.phase.max - 30_000.0,
        "max {} then {}",
        before.phase.max,
        after.phase.max
    );
    assert!(
        after.smallest_safe_shift_pct < before.smallest_safe_shift_pct - 2.0,
        "safe shift {} then {}",
        before.smallest_safe_shift_pct,
        after.smallest_safe_shift_pct
    );
}

/// Every built-in network's own warm-up leaves every default method's start out, a DCM's
/// pull-in included (one run of at most 200 000 cycles each; `ecsync compare --preset NAME`
/// at the presets' own runs and cycles said the same on 2026-12-07).
#[test]
fn no_preset_records_a_method_s_start() {
    for (name, text) in ecsync_sim::preset::NETWORKS {
        let mut s = ecsync_lab::parse(name, text).expect("the preset parses");
        s.runs = 1;
        s.cycles = s.cycles.min(200_000);
        let out = summarize(&ecsync_lab::compare(&s, 2, &AtomicU64::new(0)).expect("runs"));
        assert!(
            out.warnings.iter().all(|w| w.kind != "settling"),
            "{name}: {:?}",
            out.warnings
        );
    }
}

/// A controller that reports in sync only after the warm-up is judged on its pull-in: named,
/// with the warm-up that leaves it out, and at that warm-up it is in sync in every recorded
/// cycle (ek1100-el2828-el2889 at its former 12 s, crystals 43 ppm apart: dcm-bus-shift in
/// sync at 60 s, at 98 s before its drift ramp followed the phase's slip; 80 000 recorded
/// cycles, not the preset's 120 000, so that its pull-in still fills more than half of them).
#[test]
fn a_controller_in_sync_only_after_the_warm_up_is_named_with_the_warm_up_it_needs() {
    let text = ecsync_sim::preset::named("ek1100-el2828-el2889").expect("the preset");
    let mut s = ecsync_lab::parse("ek1100.toml", text).expect("the preset parses");
    s.methods = vec!["dcm-bus-shift".parse().expect("a method")];
    s.warmup_cycles = 12_000;
    s.cycles = 80_000;
    let out = summarize(&ecsync_lab::compare(&s, 2, &AtomicU64::new(0)).expect("runs"));
    let w = out
        .warnings
        .iter()
        .find(|w| w.kind == "settling")
        .expect("a settling warning");
    let ctl = out.methods["dcm-bus-shift"]
        .controller
        .expect("a controller");
    assert!(ctl.in_sync_fraction < 0.5, "{}", ctl.in_sync_fraction);
    let needed_s: u64 = w
        .message
        .split("a warm-up of ")
        .nth(1)
        .and_then(|m| m.split(" s ").next())
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("{}", w.message));
    assert!(
        w.message
            .starts_with("dcm-bus-shift's controller first reported in sync ")
            && (60..200).contains(&needed_s),
        "{}",
        w.message
    );
    s.warmup_cycles = needed_s * 1000;
    let out = summarize(&ecsync_lab::compare(&s, 2, &AtomicU64::new(0)).expect("runs"));
    assert!(
        out.warnings.iter().all(|w| w.kind != "settling"),
        "{:?}",
        out.warnings
    );
    let ctl = out.methods["dcm-bus-shift"]
        .controller
        .expect("a controller");
    assert_eq!(ctl.in_sync_fraction, 1.0);
}

#[path = "common/random_network.rs"]
mod random_network;

/// The warm-up a settling warning names, s: "a warm-up of N s" (a controller's) or "a warm-up
/// N s longer ... now W s" (a start's).
fn warm_up_named(message: &str) -> f64 {
    let number = |s: &str| -> f64 {
        s.split(' ')
            .next()
            .and_then(|v| v.parse().ok())
            .unwrap_or_else(|| panic!("{message}"))
    };
    if let Some(rest) = message.split("a warm-up of ").nth(1) {
        return number(rest);
    }
    let more = number(message.split("a warm-up ").nth(1).unwrap_or_default());
    let now = number(message.split("now ").nth(1).unwrap_or_default());
    now + more
}

/// True beyond the presets: on eight random networks (2-24 drives, lines and trees, crystals
/// within +-50 ppm, every default method) recorded from the end of the init frames, every
/// settling warning's warm-up
/// leaves every method's start out (rerun at the largest one named: no settling warning).
#[test]
fn the_warm_up_a_warning_names_is_enough_on_random_networks() {
    use rand::{RngExt, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0x5e771e);
    let mut warned = 0;
    for k in 0..8 {
        let n = rng.random_range(2..=24);
        let text = random_network::network(&mut rng, n);
        let mut s = ecsync_lab::parse(&format!("net{k}.toml"), &text).expect("parses");
        // Every default method, recorded from the end of their init frames.
        s.methods = ecsync_lab::parse("p.toml", ecsync_sim::preset::PAPER_2024_TOML)
            .expect("the preset")
            .methods;
        (s.warmup_cycles, s.cycles) = (10_000, 20_000);
        let out = summarize(&ecsync_lab::compare(&s, 2, &AtomicU64::new(0)).expect("runs"));
        let needed = out
            .warnings
            .iter()
            .filter(|w| w.kind == "settling")
            .map(|w| warm_up_named(&w.message))
            .fold(0.0f64, f64::max);
        if needed == 0.0 {
            continue;
        }
        warned += 1;
        s.warmup_cycles = (needed * 1e9 / f64::from(s.cycle_ns)) as u64;
        let again = summarize(&ecsync_lab::compare(&s, 2, &AtomicU64::new(0)).expect("runs"));
        assert!(
            again.warnings.iter().all(|w| w.kind != "settling"),
            "network {k} at {needed} s: {:?}\n{text}",
            again.warnings
        );
    }
    println!("{warned} of 8 networks warned of a method settling at 10 s");
    assert!(
        warned >= 4,
        "{warned} of 8 networks warned: the test tests little"
    );
}

/// A controller that never reported in sync in a recorded cycle is not ranked: its figures are
/// its pull-in. dcm-bus-shift on twelve-drives (the reference 49.9 ppm from the master) after a
/// 15 s warm-up is still ramping its drift, hundreds of microseconds off its target by the
/// ground truth; ranked, it came first under a replayed host trace for the late frames its
/// moving phase happened to miss.
#[test]
fn a_controller_never_in_sync_in_the_recording_is_not_ranked() {
    let text = ecsync_sim::preset::named("twelve-drives").expect("the preset");
    let mut s = ecsync_lab::parse("twelve-drives.toml", text).expect("the preset parses");
    s.methods = ["dcm-bus-shift", "median-fit"]
        .map(|m| m.parse().expect("a method"))
        .to_vec();
    (s.runs, s.warmup_cycles, s.cycles) = (1, 15_000, 20_000);
    let out = summarize(&ecsync_lab::compare(&s, 2, &AtomicU64::new(0)).expect("runs"));
    let dcm = &out.methods["dcm-bus-shift"];
    let ctl = dcm.controller.expect("a controller");
    assert_eq!(ctl.in_sync_fraction, 0.0);
    assert!(ctl.time_to_sync_ms.is_none());
    let off = dcm.ground_truth.offset_from_target_ns;
    assert!(off.abs() > 100_000.0, "{off} ns off its target");
    let r = &out.recommendation;
    assert_eq!(r.ranking, ["median-fit"], "{}", r.reason);
    let n = r
        .not_ranked
        .iter()
        .find(|n| n.method == "dcm-bus-shift")
        .expect("dcm-bus-shift not ranked");
    assert!(
        n.why.contains("never reported in sync") && n.why.contains("--warmup-s"),
        "{}",
        n.why
    );
}

/// The verdict itself says when its pick was still settling as the recording began, not only
/// the warnings: median-fit alone on lan9252-pair after the 10 s its init frames take starts
/// 90 us off its target by the ground truth (its first block), and its smallest safe shift
/// holds that start.
#[test]
fn the_verdict_says_when_its_pick_was_still_settling() {
    let mut s = lan9252_pair(10);
    s.methods.truncate(1);
    let c = ecsync_lab::compare(&s, 2, &AtomicU64::new(0)).expect("runs");
    let first_max = f64::from(c.results[0][0].series[2][0].max);
    assert!(first_max > 60_000.0, "median-fit's first block {first_max}");
    let out = summarize(&c);
    let r = &out.recommendation;
    assert_eq!(r.method, "median-fit");
    assert!(
        r.reason
            .contains("It was still settling when the recording began"),
        "{}",
        r.reason
    );
    // With the warm-up the warning names, not.
    let c = ecsync_lab::compare(&lan9252_pair(11), 2, &AtomicU64::new(0)).expect("runs");
    let r = summarize(&c).recommendation;
    assert!(!r.reason.contains("still settling"), "{}", r.reason);
}
