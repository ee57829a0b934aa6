//! A network whose cycle's frames take more than half the cycle on the wire (a long line):
//! its replies are not counted lost (they come back well before the next cycle); a cycle
//! shorter than the frames' way round is refused before anything is simulated, with the
//! cycle the network needs, worked out from the devices exactly as the engine lays out its
//! frames after the bring-up.

use ecsync_lab::report::summarize;
use std::sync::atomic::AtomicU64;

#[path = "common/line.rs"]
mod line;
use line::line;

#[test]
fn frames_longer_than_half_the_cycle_come_back_and_a_cycle_too_short_is_refused_before_the_bring_up()
 {
    // 150 drives: the cycle's frames take about 0.45 ms on the wire (more than half of a
    // 0.8 ms cycle) and come back within it.
    let text = line(150, 800);
    let s = ecsync_lab::parse("line-150.toml", &text).unwrap();
    let c = ecsync_lab::compare(&s, 2, &AtomicU64::new(0)).unwrap();
    let out = summarize(&c);
    for (m, mo) in &out.methods {
        let g = &mo.ground_truth;
        assert!(
            mo.ground_truth.lost_frames == 0,
            "{m}: {} of {} frames lost",
            g.lost_frames,
            mo.cycles_done
        );
    }
    let wire_ns = c
        .results
        .iter()
        .flatten()
        .map(|r| r.frame_wire_ns)
        .fold(0.0, f64::max);
    assert!(
        wire_ns > 400_000.0,
        "the frames take {wire_ns} ns on the wire"
    );
    // Both ranked but a controller that never reported in sync in the 1 500 recorded cycles
    // after the line's 1 s warm-up: its figures are its pull-in.
    let r = &out.recommendation;
    for (m, mo) in &out.methods {
        let pulling_in = mo.controller.is_some_and(|c| c.in_sync_fraction == 0.0);
        assert_eq!(r.ranking.contains(m), !pulling_in, "{m}: {r:?}");
        assert_eq!(
            r.not_ranked.iter().any(|n| &n.method == m),
            pulling_in,
            "{m}: {r:?}"
        );
    }
    assert!(!r.ranking.is_empty(), "{r:?}");
    assert!(
        !out.warnings.iter().any(|w| w.kind == "cycle_too_short"),
        "{:?}",
        out.warnings
    );

    // What the check before the bring-up works out from the devices is what the engine
    // built after it: the same frames on the wire.
    let fit = ecsync_lab::run::cycle_fit(&s).unwrap();
    assert_eq!(
        fit.wire_ns,
        (wire_ns * 1000.0).round() as u64 / 1000,
        "{fit:?}"
    );
    assert!(fit.needed_cycle_ns <= 800_000, "{fit:?}");

    // The same line at 0.4 ms: the frames alone are longer than the cycle. Nothing is
    // simulated: the error says what the network needs and which cycle to configure.
    let text = line(150, 400);
    let s = ecsync_lab::parse("line-150-short.toml", &text).unwrap();
    let t = std::time::Instant::now();
    let e = ecsync_lab::compare(&s, 2, &AtomicU64::new(0)).unwrap_err();
    let ecsync_lab::run::RunError::CycleTooShort { cycle_us, fit: f } = &e else {
        panic!("{e}");
    };
    assert_eq!((*cycle_us, *f), (400.0, fit), "{e}");
    let msg = e.to_string();
    assert!(
        msg.contains("400 us cycle is too short")
            && msg.contains(&format!(
                "set run.cycle_us (or --cycle-us) to {} or more",
                fit.suggested_cycle_us()
            )),
        "{msg}"
    );
    // (Not a timing assertion: a bring-up of 150 drives is seconds, the check milliseconds.)
    eprintln!("refused in {:?}", t.elapsed());
}
