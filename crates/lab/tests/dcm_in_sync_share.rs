//! A DCM controller's "in sync" share is of the cycles it ran: the slots its task skipped
//! after a host stall are no cycles it was out of sync in, and are reported apart.
//!
//! Before, the share's denominator was the recorded slots (the skipped ones move the cycle
//! numbers on): a controller locked throughout five stalls of 90 ms in 4 000 recorded cycles
//! read "in sync 88.75 %" (3 550 of 4 000 slots).

use ecsync_lab::report::summarize;
use ecsync_sim::fault::FaultSchedule;
use ecsync_sim::host::HostParams;
use ecsync_sim::preset::PAPER_2024_TOML;
use std::sync::atomic::AtomicU64;

const RECORDED: u64 = 4_000;
const STALLS: u64 = 5;
const STALL_MS: u64 = 90;

#[test]
fn skipped_slots_are_left_out_of_the_in_sync_share_and_counted_apart() {
    let mut s = ecsync_lab::parse("paper-2024", PAPER_2024_TOML).unwrap();
    assert_eq!(s.cycle_ns, 1_000_000, "the hand count below is at 1 ms");
    s.methods = vec![
        "dcm-bus-shift".parse().unwrap(),
        "dcm-master-shift".parse().unwrap(),
    ];
    s.runs = 1;
    s.cycles = RECORDED;
    // A host without send jitter, so that every frame's phase (the truth) is where the
    // controller's filtered error says; the master's crystal the preset's, 0.9 ppm from the
    // reference's. Both lock within a few seconds: well before the recording.
    s.host = HostParams {
        master_ppm: 13.3,
        ..HostParams::ideal()
    };
    s.warmup_cycles = 10_500;
    // Stalls every 0.6 s from 0.5 s into the recording, each shorter than the slaves'
    // watchdogs (100 ms), so nothing else happens to the segment.
    let faults: String = (0..STALLS)
        .map(|k| {
            format!(
                "[[fault]]\nat_s = {:.1}\nkind = \"host_stall\"\nstall_ms = {STALL_MS}\n",
                11.0 + 0.6 * k as f64
            )
        })
        .collect();
    s.faults = Some(FaultSchedule::parse("faults.toml", &faults).unwrap());
    let c = ecsync_lab::compare(&s, 2, &AtomicU64::new(0)).unwrap();
    let out = summarize(&c);
    for (m, runs) in ["dcm-bus-shift", "dcm-master-shift"].iter().zip(&c.results) {
        let mo = &out.methods[*m];
        let ctl = mo.controller.expect("a DCM controller log");
        let r = &runs[0];
        assert!(r.reached_end, "{m}: the stalls end inside the recording");
        assert_eq!(r.cycles_done, RECORDED, "{m}");
        // By hand: a stall of 90 ms at 1 ms skips 89 or 90 slots (the stalled cycle runs at
        // once on waking, in the slot it woke in or the one before: see the faults test).
        let (lo, hi) = (STALLS * (STALL_MS - 1), STALLS * STALL_MS);
        assert!(
            (lo..=hi).contains(&ctl.skipped_slots),
            "{m}: {} slots skipped, the stalls are {lo}..={hi}",
            ctl.skipped_slots
        );
        assert_eq!(ctl.cycles_run + ctl.skipped_slots, RECORDED, "{m}");
        // The simulator's ground truth: every recorded frame reached the reference within the
        // controller's in-sync band (5 us) of the target (no send jitter: the phase is what
        // the controller filters), so it was right to say in sync in every cycle it ran; and
        // it did.
        let g = &mo.ground_truth;
        assert!(
            g.phase_error.max_abs < 5_000.0 - 1.0,
            "{m}: |phase - target| up to {} ns",
            g.phase_error.max_abs
        );
        let t = r.controller.expect("the run's controller truth");
        println!(
            "{m}: {} cycles run, {} slots skipped, {} in sync, |phase - target| max {:.0} ns",
            ctl.cycles_run, ctl.skipped_slots, t.in_sync_cycles, g.phase_error.max_abs
        );
        assert_eq!(t.sync_losses, 0, "{m}: {t:?}");
        assert_eq!(t.in_sync_cycles, ctl.cycles_run, "{m}: {t:?}");
        assert_eq!(
            ctl.in_sync_fraction, 1.0,
            "{m}: in sync over {} cycles run, {} slots skipped",
            ctl.cycles_run, ctl.skipped_slots
        );
    }
}
