//! Acceptance 1 of issue 10, a property over 50 random networks (2-24 drives in lines and
//! trees, master and slave crystals uniform in +-50 ppm, the loaded PREEMPT_RT host, SYNC0 at
//! 30 %): `median-fit` has no late frame and holds its target within 10 us on every one;
//! `median`'s offset is reported, and warned about exactly when it eats more than 10 % of the
//! margin. The networks are drawn from a fixed seed, so a failure reproduces.

use ecsync_lab::report::summarize;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::sync::atomic::AtomicU64;

#[path = "common/random_network.rs"]
mod random_network;
use random_network::network;

#[test]
fn median_fit_holds_its_target_on_fifty_random_networks() {
    let mut rng = ChaCha8Rng::seed_from_u64(0x15_5e10);
    let mut warned = 0;
    let (mut worst_fit_ns, mut worst_median_ns) = (0.0f64, 0.0f64);
    for k in 0..50 {
        let n = rng.random_range(2..=24);
        let text = network(&mut rng, n);
        let s = ecsync_lab::parse(&format!("net{k}.toml"), &text)
            .unwrap_or_else(|e| panic!("network {k}: {e}\n{text}"));
        let c = ecsync_lab::compare(&s, 2, &AtomicU64::new(0))
            .unwrap_or_else(|e| panic!("network {k}: {e}\n{text}"));
        let out = summarize(&c);
        let fit = &out.methods["median-fit"].ground_truth;
        assert_eq!(fit.late_frames, 0, "network {k} ({n} drives)\n{text}");
        assert!(
            fit.offset_from_target_ns.abs() <= 10_000.0,
            "network {k}: median-fit {} ns off its target\n{text}",
            fit.offset_from_target_ns
        );
        let med = &out.methods["median"];
        let off = med.ground_truth.offset_from_target_ns;
        assert!(off.is_finite(), "network {k}: median's offset is reported");
        assert!(
            med.init_drift.is_some(),
            "network {k}: median's init drift is reported"
        );
        let eats = off.abs() > 0.1 * out.margin_budget_ns;
        let warning = out
            .warnings
            .iter()
            .any(|w| w.kind == "off_target" && w.method.as_deref() == Some("median"));
        assert_eq!(
            eats, warning,
            "network {k}: median {off} ns off, margin {} ns, warnings {:?}",
            out.margin_budget_ns, out.warnings
        );
        warned += usize::from(warning);
        worst_fit_ns = worst_fit_ns.max(fit.offset_from_target_ns.abs());
        worst_median_ns = worst_median_ns.max(off.abs());
    }
    println!(
        "50 networks: median-fit at most {:.2} us off its target, 0 late frames; median at most {:.1} us off, warned on {warned}",
        worst_fit_ns / 1000.0,
        worst_median_ns / 1000.0
    );
    // Crystals within +-50 ppm move median off by up to ~500 us: most networks warn.
    assert!(
        warned >= 10,
        "only {warned} of 50 networks warned about median"
    );
}

/// Issue 12 on random networks: on 12 of them (2-24 drives, lines and trees, crystals within
/// +-50 ppm), a random drive's power cycle and then the reference's: the master brings each
/// back (the slave it was, nothing else) and `median-fit` and `dcm-master-shift` are locked
/// again within two seconds of its return (the slowest is printed).
#[test]
fn power_cycles_are_recovered_on_twelve_random_networks() {
    use ecsync_dc::MethodKind;
    let mut rng = ChaCha8Rng::seed_from_u64(0x12_fa17);
    let mut worst = 0.0f64;
    for k in 0..12 {
        let n = rng.random_range(2..=24);
        let text = network(&mut rng, n);
        let mut s = ecsync_lab::parse(&format!("net{k}.toml"), &text)
            .unwrap_or_else(|e| panic!("network {k}: {e}\n{text}"));
        s.methods = vec![MethodKind::MedianFit, MethodKind::DcmMasterShift];
        s.cycles = 5_000;
        let victim = rng.random_range(2..=n);
        let faults = format!(
            "[[fault]]\nat_s = 11\nfor_s = 0.2\nkind = \"power_cycle\"\nslave = {victim}\n\n\
             [[fault]]\nat_s = 13\nfor_s = 0.2\nkind = \"power_cycle\"\nslave = \"reference\"\n"
        );
        s.faults = Some(ecsync_sim::fault::FaultSchedule::parse("faults.toml", &faults).unwrap());
        let c = ecsync_lab::compare(&s, 2, &AtomicU64::new(0))
            .unwrap_or_else(|e| panic!("network {k}: {e}\n{text}"));
        let out = summarize(&c);
        for (m, mo) in &out.methods {
            let f = &mo.faults[0];
            // What each recovery found reset (the slaves it names minus those that had only
            // left OP on their process data watchdog, behind the power-cycled one).
            let back: Vec<Vec<u16>> = f
                .recoveries
                .iter()
                .filter(|r| !r.slaves.is_empty())
                .map(|r| {
                    let watchdog: Vec<u16> = r
                        .left_op
                        .iter()
                        .filter_map(|l| {
                            assert!(l.contains("0x001b"), "{m}: {l}");
                            l.strip_prefix("slave ")?.split(' ').next()?.parse().ok()
                        })
                        .collect();
                    r.slaves
                        .iter()
                        .copied()
                        .filter(|s| !watchdog.contains(s))
                        .collect()
                })
                .collect();
            // The reference is the first slave (position 1); a victim behind it comes back
            // with it only if it is the reference itself.
            let want: Vec<Vec<u16>> = if victim == 1 {
                vec![vec![1], vec![1]]
            } else {
                vec![vec![victim as u16], vec![1]]
            };
            assert_eq!(
                back, want,
                "network {k} ({n} drives, victim {victim}), {m}: {:?}\n{text}",
                f.recoveries
            );
            for (j, ms) in f.relock_ms.iter().enumerate() {
                let ms = ms.unwrap_or_else(|| {
                    panic!("network {k} ({n} drives), {m}: fault {j} never re-locked\n{text}")
                });
                println!(
                    "network {k} ({n} drives, victim {victim}), {m}: fault {j} re-locked in {ms:.0} ms"
                );
                worst = worst.max(ms);
                // The paper network's drives come back within 120 ms; crystals up to 100 ppm
                // apart need the static drift compensation's thousands of frames.
                assert!(
                    ms < 2_000.0,
                    "network {k}, {m}: fault {j} re-locked after {ms} ms"
                );
            }
        }
    }
    println!("slowest re-lock over the networks: {worst:.0} ms");
}

/// Issue 13, acceptance 3, on random networks: with a SYNC0 shift too small for the loaded
/// host's jitter (4 %), every drive of every method counts in 0x1C32:0B exactly the SYNC0
/// pulses the ground truth finds without new outputs at that drive (frames' last bits against
/// the grid), and the last drive's count is the ground truth's; pulses missed never exceed the
/// late frames (a late frame right after a late one is not another miss).
#[test]
fn drives_count_the_ground_truths_sync0_misses_on_eight_random_networks() {
    let mut rng = ChaCha8Rng::seed_from_u64(0x13_0b);
    let mut missed_total = 0;
    for k in 0..8 {
        let n = rng.random_range(2..=16);
        let text = network(&mut rng, n)
            .replace("sync0_shift_pct = 30", "sync0_shift_pct = 4")
            .replace("cycles = 12000", "cycles = 3000")
            .replace(
                "methods = [\"median\", \"median-fit\"]",
                "methods = [\"median-fit\", \"pi-m2s\", \"bus-shift\", \"snap\"]",
            );
        let s = ecsync_lab::parse(&format!("net{k}.toml"), &text)
            .unwrap_or_else(|e| panic!("network {k}: {e}\n{text}"));
        let c = ecsync_lab::compare(&s, 2, &AtomicU64::new(0))
            .unwrap_or_else(|e| panic!("network {k}: {e}\n{text}"));
        let out = summarize(&c);
        for (m, mo) in &out.methods {
            let g = &mo.ground_truth;
            let drives: Vec<_> = g
                .per_slave
                .iter()
                .filter(|s| s.drive_sm_events_missed.is_some())
                .collect();
            assert_eq!(drives.len(), n - usize::from(text.contains("junction-mii")));
            for s in &drives {
                assert_eq!(
                    s.drive_sm_events_missed,
                    Some(s.sync0_missed),
                    "network {k}, {m}, drive at {}\n{text}",
                    s.position
                );
                assert!(s.sync0_missed <= s.late_frames, "network {k}, {m}");
                missed_total += s.sync0_missed;
            }
        }
    }
    assert!(
        missed_total > 1_000,
        "the shift was not too small: {missed_total} missed"
    );
}

/// The cyclic phase starts on the reference's grid wherever the reference's crystal took its
/// time during the bring-up: on 12 random networks (crystals within +-50 ppm, the master's
/// too, so the reference runs up to 100 ppm from the master's clock over a bring-up of tens of
/// seconds), the letter's `median`, which holds the phase its init frames had, sits off its
/// target by what the drift over its init frames accounts for, plus the loaded host's mean
/// scheduling delay (j_s folded, sigma 16 us: 12.8 us; the master cannot know it), and
/// nothing more.
#[test]
fn the_first_cycle_aims_at_the_reference_s_grid_on_twelve_random_networks() {
    let mut rng = ChaCha8Rng::seed_from_u64(0x011f_1257);
    let js_mean_ns = 16_000.0 * (2.0f64 / std::f64::consts::PI).sqrt();
    let mut worst_ns = 0.0f64;
    for k in 0..12 {
        let n = rng.random_range(2..=24);
        let text = network(&mut rng, n)
            .replace("cycles = 12000", "cycles = 2000")
            .replace(
                "methods = [\"median\", \"median-fit\"]",
                "methods = [\"median\"]",
            );
        let s = ecsync_lab::parse(&format!("net{k}.toml"), &text)
            .unwrap_or_else(|e| panic!("network {k}: {e}\n{text}"));
        let c = ecsync_lab::compare(&s, 2, &AtomicU64::new(0))
            .unwrap_or_else(|e| panic!("network {k}: {e}\n{text}"));
        let out = summarize(&c);
        let med = &out.methods["median"];
        let off = med.ground_truth.offset_from_target_ns;
        let init = med.init_drift.expect("median's init drift");
        // The letter's loop (eq. 12-14, gain k = 0.01) follows the drift's ramp of d per
        // cycle d / k behind.
        let lag_ns = init.drift_ns_per_cycle / 0.01;
        let rest = off - init.offset_ns - lag_ns - js_mean_ns;
        println!(
            "network {k} ({n} drives): median {:.1} us off; the init drift accounts for {:.1} us, the loop's lag behind it {:.1} us, the host's mean delay {:.1} us: {:.1} us left",
            off / 1e3,
            init.offset_ns / 1e3,
            lag_ns / 1e3,
            js_mean_ns / 1e3,
            rest / 1e3
        );
        // What is left is the sampled j_s against its mean (0.5 us at most on these).
        assert!(
            rest.abs() < 2_000.0,
            "network {k}: median {off} ns off its target, {rest} ns unexplained (the first cycle missed the reference's grid)\n{text}"
        );
        worst_ns = worst_ns.max(rest.abs());
    }
    println!("largest unexplained offset: {:.1} us", worst_ns / 1e3);
}

/// Issue 34, acceptance 1, on random networks: drives replaced by oversampling terminals (2 to
/// 20 samples a 1 ms cycle, on SYNC1, which ecsync's master puts on the grid) count in
/// 0x1C32:0B exactly the SYNC1 events the ground truth finds without a new block, as the
/// drives on SYNC0 beside them count their pulses, with a shift small enough (4 %) that the
/// loaded host's frames miss some.
#[test]
fn oversampling_terminals_count_the_ground_truths_misses_on_six_random_networks() {
    let mut rng = ChaCha8Rng::seed_from_u64(0x34_01);
    let (mut terminals, mut missed_total) = (0, 0);
    for k in 0..6 {
        let n = rng.random_range(2..=12);
        let text = network(&mut rng, n)
            .replace("sync0_shift_pct = 30", "sync0_shift_pct = 4")
            .replace("cycles = 12000", "cycles = 3000")
            .replace(
                "methods = [\"median\", \"median-fit\"]",
                "methods = [\"median-fit\", \"bus-shift\", \"kalman\"]",
            );
        // Every other drive (at least one) an oversampling terminal.
        let mut parts: Vec<String> = text
            .split("[[segment.slave]]")
            .map(str::to_string)
            .collect();
        let mut made = 0;
        for (i, p) in parts.iter_mut().enumerate().skip(1) {
            if p.contains("device = \"servo-drive\"") && (i % 2 == 1 || made == 0) {
                let samples = [2, 4, 5, 8, 10, 20][rng.random_range(0..6)];
                *p = p.replace(
                    "device = \"servo-drive\"",
                    &format!("device = \"oversampling-terminal\"\noversampling = {samples}"),
                );
                made += 1;
            }
        }
        terminals += made;
        let text = parts.join("[[segment.slave]]");
        let s = ecsync_lab::parse(&format!("over{k}.toml"), &text)
            .unwrap_or_else(|e| panic!("network {k}: {e}\n{text}"));
        let c = ecsync_lab::compare(&s, 2, &AtomicU64::new(0))
            .unwrap_or_else(|e| panic!("network {k}: {e}\n{text}"));
        let out = summarize(&c);
        for (m, mo) in &out.methods {
            // The terminals, and only they, are marked as running on SYNC1.
            let on_sync1 = mo.ground_truth.per_slave.iter().filter(|s| s.on_sync1);
            assert_eq!(on_sync1.count(), made, "network {k}, {m}\n{text}");
            let counted: Vec<_> = mo
                .ground_truth
                .per_slave
                .iter()
                .filter(|s| s.drive_sm_events_missed.is_some())
                .collect();
            assert_eq!(
                counted.len(),
                n - usize::from(text.contains("junction-mii"))
            );
            for s in &counted {
                assert_eq!(
                    s.drive_sm_events_missed,
                    Some(s.sync0_missed),
                    "network {k}, {m}, slave at {}\n{text}",
                    s.position
                );
                missed_total += s.sync0_missed;
            }
        }
    }
    println!("{terminals} terminals, {missed_total} events missed in all");
    assert!(
        missed_total > 100,
        "the shift was not too small: {missed_total} missed"
    );
}
