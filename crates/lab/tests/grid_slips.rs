//! A master whose cycles leave SYNC0's count: ethercrab's snap (`next_cycle_wait`) waits from
//! its send to the reference's next grid point, so a frame that reaches the reference just
//! before a grid point makes it send again at once. Sent without jitter (`spin`, `txtime`)
//! its frames sit right at the grid point and that happens every few cycles: the ground truth
//! judged those frames against the grid point the master's cycle count aimed at, a period
//! further each time, and reported a mean phase of -3.4 s and a margin of +3.4 s, and the
//! verdict recommended it. Now the ground truth follows the master's schedule (a cycle started
//! less than half a period after the one before aims at the same grid point), counts each
//! such slip, and the method is not ranked.

use ecsync_lab::report::summarize;
use std::sync::atomic::AtomicU64;

fn scenario(send: &str) -> ecsync_lab::scenario::Scenario {
    let mut t = ecsync_sim::preset::PAPER_2024_TOML.to_string();
    for (from, to) in [
        ("runs = 5", "runs = 1".to_string()),
        ("cycles = 1800000", "cycles = 20000".to_string()),
        ("warmup_s = 120", "warmup_s = 12".to_string()),
    ] {
        assert!(t.contains(from), "the preset has `{from}`");
        t = t.replacen(from, &to, 1);
    }
    let m = t.find("\nmethods = [").expect("the preset's methods") + 1;
    let end = m + t[m..].find('\n').unwrap();
    t.replace_range(m..end, "methods = [\"snap\", \"median-fit\"]");
    t.push_str(&format!("\n[send]\nmodes = [\"{send}\"]\n"));
    ecsync_lab::parse("paper-2024-slips.toml", &t).unwrap_or_else(|e| panic!("{e}\n{t}"))
}

#[test]
fn snap_sent_without_jitter_slips_cycles_and_is_judged_by_the_grid_point_it_aimed_at() {
    for send in ["spin", "txtime"] {
        let s = scenario(send);
        let period_ns = 1e6;
        let out = summarize(&ecsync_lab::compare(&s, 2, &AtomicU64::new(0)).unwrap());
        let snap = &out.methods[&format!("snap+{send}")];
        let fit = &out.methods[&format!("median-fit+{send}")];
        println!(
            "{send}: snap {} slips, mean {:.1} us, min {:.1} us; median-fit {} slips",
            snap.grid_slips,
            snap.ground_truth.offset_from_target_ns / 1e3,
            snap.ground_truth.phase.min / 1e3,
            fit.grid_slips
        );
        // Snap meets a grid point from just before it in a good share of the cycles.
        assert!(snap.grid_slips > 1_000, "{send}: {} slips", snap.grid_slips);
        // Every frame within half a cycle of the target: the grid point nearest it.
        let g = &snap.ground_truth;
        assert!(g.phase.min - (g.target_phase_ns as f64) > -period_ns / 2.0);
        assert!(g.phase.max - (g.target_phase_ns as f64) < period_ns / 2.0);
        assert!(g.sync0_margin.mean < period_ns, "a margin within the cycle");
        // Frames more often than pulses: no pulse without new outputs (counted from the
        // pulses between outputs, whatever grid point a frame is put to).
        assert!(
            g.per_slave
                .iter()
                .all(|p| p.sync0_missed == 0 && p.late_frames == 0)
        );
        // A method that holds its cycle has none and is the one recommended.
        assert_eq!(fit.grid_slips, 0, "{send}");
        let r = &out.recommendation;
        assert_eq!(r.method, format!("median-fit+{send}"));
        let why = &r
            .not_ranked
            .iter()
            .find(|n| n.method == format!("snap+{send}"))
            .expect("snap not ranked")
            .why;
        assert!(why.contains("one frame per SYNC0 cycle"), "{why}");
    }
}
