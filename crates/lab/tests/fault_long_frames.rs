//! A `delay` fault that holds replies past the cycle is named as the cause of the long frames,
//! not the cycle ("make the cycle longer" was wrong advice); a network whose frames fit the
//! cycle outside the fault keeps that figure, and without the fault no warning is given.

use ecsync_lab::report::summarize;
use std::sync::atomic::AtomicU64;

fn scenario(faults: Option<&str>) -> ecsync_lab::Scenario {
    let text = ecsync_sim::preset::PAPER_2024_TOML;
    let mut s = ecsync_lab::parse("paper-2024", text).unwrap();
    s.runs = 1;
    s.cycles = 2000;
    s.warmup_cycles = 12_000;
    s.methods = vec![ecsync_dc::MethodKind::MedianFit];
    s.faults = faults.map(|f| ecsync_sim::fault::FaultSchedule::parse("f.toml", f).unwrap());
    s
}

#[test]
fn a_delay_fault_is_blamed_for_its_long_frames_not_the_cycle() {
    // 5 ms on every reply for 10 ms of the recorded cycles, after a short loss burst (a fault
    // that holds nothing back).
    let extra_us = 5000.0;
    let s = scenario(Some(&format!(
        "[[fault]]\nat_s = 12.2\nkind = \"loss\"\nframes = 2\n\n[[fault]]\nat_s = 12.5\nfor_s = 0.01\nkind = \"delay\"\nextra_us = {extra_us}\n"
    )));
    let c = ecsync_lab::compare(&s, 1, &AtomicU64::new(0)).unwrap();
    let r = c.results.iter().flatten().next().unwrap();
    let period = f64::from(s.cycle_ns);
    // The longest frame is the fault's: its delay and the network's way round.
    assert!(
        r.max_round_trip_ns >= extra_us * 1000.0
            && r.max_round_trip_ns < extra_us * 1000.0 + period,
        "{}",
        r.max_round_trip_ns
    );
    assert_eq!(r.longest_frame_fault, Some(1));
    assert!(
        r.max_round_trip_unfaulted_ns < period,
        "{}",
        r.max_round_trip_unfaulted_ns
    );
    let w = summarize(&c).warnings;
    assert!(!w.iter().any(|w| w.kind == "cycle_too_short"), "{w:?}");
    let f = w
        .iter()
        .find(|w| w.kind == "fault_long_frames")
        .unwrap_or_else(|| panic!("{w:?}"));
    assert!(
        f.message.contains("inside the window of fault[1] (delay)")
            && f.message.contains("its delay of 5000.0 us")
            && !f.message.contains("make the cycle longer"),
        "{}",
        f.message
    );

    // Without the fault: the same frames, no long one, no warning.
    let c = ecsync_lab::compare(&scenario(None), 1, &AtomicU64::new(0)).unwrap();
    let q = c.results.iter().flatten().next().unwrap();
    assert_eq!(q.longest_frame_fault, None);
    assert_eq!(q.max_round_trip_ns, q.max_round_trip_unfaulted_ns);
    assert!(q.max_round_trip_ns < period);
    let w = summarize(&c).warnings;
    assert!(
        !w.iter()
            .any(|w| w.kind == "cycle_too_short" || w.kind == "fault_long_frames"),
        "{w:?}"
    );
}
