//! The SM-event-missed count 0x1C32:0B under faults, the drives' own against the ground
//! truth's (SYNC0 pulses in OP with no new outputs since the one before): a drive cut off from
//! its frames counts the pulses until its process data watchdog takes it out of OP, none while
//! it is out of OP, and a power-cycled drive's counter (a RAM value) starts again from 0, so its
//! count is the ground truth's since its restart.

use ecsync_lab::report::summarize;
use ecsync_sim::fault::FaultSchedule;
use ecsync_sim::preset::PAPER_2024_TOML;
use std::sync::atomic::AtomicU64;

/// paper-2024, one run of 3 000 recorded cycles after 0.5 s of warm-up, dcm-master-shift
/// (no init frames), with `faults` from the start of the cyclic phase.
fn compare_with(faults: &str) -> ecsync_lab::report::SummaryOut {
    let mut s = ecsync_lab::parse("paper-2024", PAPER_2024_TOML).unwrap();
    s.runs = 1;
    s.cycles = 3_000;
    s.warmup_cycles = 500;
    s.methods.retain(|k| k.name() == "dcm-master-shift");
    s.faults = Some(FaultSchedule::parse("faults.toml", faults).unwrap());
    summarize(&ecsync_lab::compare(&s, 1, &AtomicU64::new(0)).unwrap())
}

/// Drive 3 (position 2) power-cycled for 200 ms at 1.5 s, 5 % of the frames lost from 0.6 s to
/// 3.4 s: drives 4-6, cut off behind it for longer than their 100 ms watchdog, leave OP. Each
/// drive's own count equals the ground truth's (drive 3's since its restart, which is less than
/// the whole and more than none: frames were lost before and after it), and the drives cut off
/// counted about the watchdog's 100 pulses, not the 200 ms they were cut off for or the time
/// until they were back in OP.
#[test]
fn a_power_cycled_drive_counts_from_its_restart_and_the_others_as_the_truth() {
    let out = compare_with(
        "[[fault]]\nat_s = 0.6\nfor_s = 2.8\nkind = \"loss\"\nprobability = 0.05\n\n\
         [[fault]]\nat_s = 1.5\nfor_s = 0.2\nkind = \"power_cycle\"\nslave = 3\n",
    );
    let mo = &out.methods["dcm-master-shift"];
    let per_slave = &mo.ground_truth.per_slave;
    assert_eq!(per_slave.len(), 6);
    let loss_only = per_slave[0].sync0_missed;
    assert!(loss_only > 20, "the loss cost pulses: {:?}", per_slave[0]);
    for s in per_slave {
        let drive = s
            .drive_sm_events_missed
            .unwrap_or_else(|| panic!("{}: runs on SYNC0: {s:?}", s.name));
        if s.position == 2 {
            assert_eq!(s.drive_restarts, 1, "{s:?}");
            let since = s.sync0_missed_since_drive_restart.unwrap();
            assert_eq!(
                drive, since,
                "{}: its count since its restart: {s:?}",
                s.name
            );
            assert!(0 < since && since < s.sync0_missed, "{s:?}");
            assert!(s.drive_count_shown().ends_with('*'));
            assert!(
                s.restart_note()
                    .unwrap()
                    .contains(&format!("against {since} pulses"))
            );
        } else {
            assert_eq!(s.drive_restarts, 0, "{s:?}");
            assert_eq!(s.sync0_missed_since_drive_restart, None);
            assert_eq!(drive, s.sync0_missed, "{}: {s:?}", s.name);
        }
        if s.position > 2 {
            // The cut: 99 pulses after the first that took the last outputs, up to the
            // watchdog's expiry 100 ms after them; then the loss's pulses while it was in OP
            // (not those of the ~250 cycles until it was back in OP).
            let m = s.sync0_missed;
            assert!(99 < m && m < 99 + loss_only, "{}: {m}: {s:?}", s.name);
        }
    }
}

#[path = "common/line.rs"]
mod line;

/// A line of 300 drives, whose cycle takes several frames, with 5 % of the frames lost all
/// through: each frame is lost on its own, so the drives behind different frames miss
/// different pulses, and each drive's own count equals the ground truth's. A cycle whose
/// first frame (the reference's time) was lost on its way out still has its other frames'
/// drives judged: they took their outputs (the truth counted a missed pulse for each of them
/// before).
#[test]
fn in_a_cycle_of_several_frames_each_drive_counts_its_own_frames_losses() {
    let mut s = ecsync_lab::parse("line-300.toml", &line::line(300, 2000)).unwrap();
    s.methods.retain(|k| k.name() == "soem-pi");
    s.faults = Some(
        FaultSchedule::parse(
            "faults.toml",
            "[[fault]]\nat_s = 0\nkind = \"loss\"\nprobability = 0.05\n",
        )
        .unwrap(),
    );
    let c = ecsync_lab::compare(&s, 1, &AtomicU64::new(0)).unwrap();
    let frames = ecsync_lab::run::cycle_fit(&s).unwrap().frames;
    assert!(frames >= 4, "{frames} frames a cycle");
    let out = summarize(&c);
    let per_slave = &out.methods["soem-pi"].ground_truth.per_slave;
    assert_eq!(per_slave.len(), 300);
    let mut counts = std::collections::BTreeSet::new();
    for d in per_slave {
        let own = d.drive_sm_events_missed.expect("a drive in DC mode");
        assert_eq!(own, d.sync0_missed, "{}: {d:?}", d.name);
        counts.insert(own);
    }
    // About 5 % x 1 500 / 2 lost on their way out per frame (the rest on their way back,
    // after the drives took the outputs), each frame its own.
    assert!(counts.len() > 1, "{counts:?}");
    assert!(counts.iter().all(|&n| (10..=80).contains(&n)), "{counts:?}");
    // The lost count is of cycles: it says so, with the frames a cycle sends.
    let w = out
        .warnings
        .iter()
        .find(|w| w.kind == "lost_frames")
        .unwrap();
    assert!(
        w.message.contains(&format!(
            "recorded cycles lost one or more of their {frames} frames"
        )),
        "{}",
        w.message
    );
}
